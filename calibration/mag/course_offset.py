"""The constant heading offset (the swing fit's coefficient A) from GNSS course over ground.

After a field fit the magnetometer heading ψ can still be off by a constant A: a rotation about the vertical
inside the soft iron (sensor yaw misalignment to the hull) leaves the field magnitude and the vertical
component unchanged, so no field fit sees it on level data. GNSS course over ground χ is a heading reference
while the vehicle moves straight, with two differences from heading:

- **Current / wind drift.** A vehicle moving through the water (air) at V_w on true heading ψt, carried by a
  constant current c = (c_N, c_E), moves over ground at v = V_w·(cos ψt, sin ψt) + c, so
  sin(χ − ψt) = (c_E·cos ψt − c_N·sin ψt)/|v|. The drift angle depends on the heading like a sin/cos term,
  and reverses on the opposite heading; a constant offset A does not. With headings on both sides of the
  circle the linear least squares

      χ − ψ = A + (c_E·cos ψ − c_N·sin ψ)/|v|

  separates A from (c_N, c_E). On one heading (or one half of the circle) they cannot be separated: then A
  alone is fitted and the report says the offset includes any drift. A drift that is constant in the *body*
  frame (leeway of a hull that crabs the same way on every heading, a sideslipping rover) is a constant
  course − heading difference and cannot be told from A by any data: it becomes part of the offset.
- **Turns and latency.** In a turn the course lags the heading (sideslip) and a latency error τ shifts the
  comparison by τ·ψ̇. Only straight, steady segments are used: the heading rate stays below
  `max_turn_rate_deg_s` for ±window_s/2 around the fix, and the course is compared with the heading at the
  fix's time of validity (the caller stamps each course with it: arrival time minus the receiver latency).

Course noise: the receiver's speed accuracy s_acc gives σ_χ ≈ s_acc/|v| (rad); without it
DEFAULT_COURSE_SIGMA_DEG. A's 1σ comes from the normal matrix, scaled by the measured residual when that is
larger than the assumed noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ahrsd.core.angles import wrap_pi

from .swing import DEFAULT_MIN_SPEED_M_S, heading_span_deg

DEFAULT_MAX_TURN_RATE_DEG_S = 2.0   # "straight": a 0.1 s latency error then costs < 0.2° (our choice)
DEFAULT_STRAIGHT_WINDOW_S = 2.0     # the heading rate must stay low this long around a fix
DEFAULT_COURSE_SIGMA_DEG = 0.5      # course noise when the receiver gives no speed accuracy (our choice)
MIN_COURSE_SIGMA_DEG = 0.05
OUTLIER_DEG = 10.0                  # course − heading this far from the median: a manoeuvre, not drift
MIN_FIXES = 10
MIN_SPAN_FOR_CURRENT_DEG = 180.0    # the current needs headings on both sides of the circle


@dataclass(frozen=True)
class CourseOffsetFit:
    """offset_deg: add it to the magnetometer heading (true = measured + A). std_deg: its 1σ.
    current_ne_m_s: the fitted current (north, east), None when it could not be separated from A.
    refused: why no offset was fitted (then offset_deg is NaN)."""

    offset_deg: float
    std_deg: float
    n_used: int
    n_offered: int
    current_ne_m_s: tuple | None = None
    current_std_m_s: float = math.nan
    residual_rms_deg: float = math.nan
    refused: str | None = None
    notes: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"offset_deg": self.offset_deg, "std_deg": self.std_deg, "n_used": self.n_used,
                "n_offered": self.n_offered,
                "current_ne_m_s": None if self.current_ne_m_s is None else list(self.current_ne_m_s),
                "current_std_m_s": self.current_std_m_s, "residual_rms_deg": self.residual_rms_deg,
                "refused": self.refused, "notes": list(self.notes)}


def _refused(reason: str, n_offered: int, n_used: int = 0) -> CourseOffsetFit:
    return CourseOffsetFit(math.nan, math.inf, n_used, n_offered, refused=reason)


def straight_mask(fix_t_s: np.ndarray, heading_t_s: np.ndarray, heading_rate_rad_s: np.ndarray,
                  max_turn_rate_deg_s: float, window_s: float) -> np.ndarray:
    """True for fixes around which |heading rate| stays below the limit for ±window_s/2 (and heading samples
    exist there)."""
    rate = np.abs(np.asarray(heading_rate_rad_s, dtype=np.float64))
    lo = np.searchsorted(heading_t_s, fix_t_s - window_s / 2, side="left")
    hi = np.searchsorted(heading_t_s, fix_t_s + window_s / 2, side="right")
    limit = math.radians(max_turn_rate_deg_s)
    out = np.zeros(fix_t_s.shape, dtype=bool)
    for k in range(fix_t_s.size):
        if hi[k] > lo[k]:
            out[k] = bool(np.all(rate[lo[k]:hi[k]] <= limit))
    return out


def fit_course_offset(fix_t_s, course_rad, ground_speed_m_s, speed_acc_m_s, heading_t_s, heading_rad,
                      heading_rate_rad_s, *, min_speed_m_s: float = DEFAULT_MIN_SPEED_M_S,
                      max_turn_rate_deg_s: float = DEFAULT_MAX_TURN_RATE_DEG_S,
                      window_s: float = DEFAULT_STRAIGHT_WINDOW_S) -> CourseOffsetFit:
    """A (and the current) from course fixes (time of validity, true course, ground speed, speed accuracy
    1σ or NaN) against the magnetometer's true heading (times, rad, heading rate rad/s) of the same vehicle
    axis. See the module docstring for the model."""
    tc = np.asarray(fix_t_s, dtype=np.float64).reshape(-1)
    chi = np.asarray(course_rad, dtype=np.float64).reshape(-1)
    v = np.asarray(ground_speed_m_s, dtype=np.float64).reshape(-1)
    sacc = np.broadcast_to(np.asarray(speed_acc_m_s, dtype=np.float64), tc.shape)
    th = np.asarray(heading_t_s, dtype=np.float64).reshape(-1)
    psi = np.asarray(heading_rad, dtype=np.float64).reshape(-1)
    n_offered = int(tc.size)
    ok = _fixes_on_straight_runs(tc, chi, v, th, heading_rate_rad_s, min_speed_m_s, max_turn_rate_deg_s, window_s)
    if isinstance(ok, str):
        return _refused(ok, n_offered)
    if ok.sum() < MIN_FIXES:
        return _refused(f"only {int(ok.sum())} course fixes on straight runs above {min_speed_m_s:.1f} m/s "
                        f"(need {MIN_FIXES}): hold a few straight courses for some seconds", n_offered, int(ok.sum()))
    delta, speed, sig, psi_k = _consistent_course_offsets(tc[ok], chi[ok], v[ok], sacc[ok], th, psi)
    n = int(delta.size)
    if n < MIN_FIXES:
        return _refused(f"only {n} consistent course fixes", n_offered, n)
    return _fit_offset_and_current(delta, speed, sig, psi_k, n_offered)


def _fixes_on_straight_runs(tc, chi, v, th, heading_rate_rad_s, min_speed_m_s, max_turn_rate_deg_s,
                            window_s) -> np.ndarray | str:
    """The fixes the fit may use (finite, within the heading's time span, fast enough, on a straight run), or why
    none can be."""
    if tc.size == 0:
        return "no GNSS course received"
    if th.size < 2:
        return "no heading samples"
    ok = np.isfinite(tc) & np.isfinite(chi) & np.isfinite(v) & (tc >= th[0]) & (tc <= th[-1])
    if not np.any(ok & (v >= min_speed_m_s)):
        return f"GNSS speed never reached {min_speed_m_s:.1f} m/s (course is noise when slow)"
    ok &= v >= min_speed_m_s
    ok &= straight_mask(tc, th, heading_rate_rad_s, max_turn_rate_deg_s, window_s)
    return ok


def _consistent_course_offsets(tc, chi, speed, sacc, th, psi):
    """Course minus the interpolated heading at each fix, with its speed, its 1σ (rad: the speed accuracy over
    the speed, else DEFAULT_COURSE_SIGMA_DEG, at least MIN_COURSE_SIGMA_DEG) and the heading there, without the
    outliers (a manoeuvre the straight gate missed, a course glitch: far from the circular median)."""
    psi_at = np.interp(tc, th, np.unwrap(psi))
    delta = wrap_pi(chi - psi_at)
    sig = np.where(np.isfinite(sacc) & (sacc > 0), sacc / speed, math.radians(DEFAULT_COURSE_SIGMA_DEG))
    sig = np.maximum(sig, math.radians(MIN_COURSE_SIGMA_DEG))
    med = math.atan2(float(np.median(np.sin(delta))), float(np.median(np.cos(delta))))
    keep = np.abs(wrap_pi(delta - med)) <= math.radians(OUTLIER_DEG)
    return wrap_pi(delta[keep] - med) + med, speed[keep], sig[keep], psi_at[keep]


def _fit_offset_and_current(delta, speed, sig, psi_k, n_offered: int) -> CourseOffsetFit:
    """The weighted least-squares fit of the module docstring's model: the offset A, and the current when the
    straight courses span enough headings to tell it from A."""
    n = int(delta.size)
    notes: list[str] = []
    span = heading_span_deg(np.degrees(psi_k))
    with_current = span >= MIN_SPAN_FOR_CURRENT_DEG
    cols = [np.ones(n)]
    if with_current:
        cols += [np.cos(psi_k) / speed, -np.sin(psi_k) / speed]
    else:
        notes.append(f"straight courses span only {span:.0f} deg: a current cannot be separated from the offset "
                     "(it is included in it); steer opposite courses to separate them")
    x = np.column_stack(cols) / sig[:, None]
    y = delta / sig
    coef, *_ = np.linalg.lstsq(x, y, rcond=None)
    res = y - x @ coef
    dof = max(n - x.shape[1], 1)
    scale2 = max(float(res @ res) / dof, 1.0)
    cov = np.linalg.pinv(x.T @ x) * scale2
    a_deg = math.degrees(float(coef[0]))
    out_std = math.degrees(math.sqrt(max(cov[0, 0], 0.0)))
    current = None
    current_std = math.nan
    if with_current:
        current = (float(coef[2]), float(coef[1]))        # (north, east)
        current_std = float(math.sqrt(max(cov[1, 1] + cov[2, 2], 0.0) / 2))
    resid_deg = math.degrees(float(np.sqrt(np.mean((res * sig) ** 2))))
    return CourseOffsetFit(a_deg, out_std, n, n_offered, current, current_std, resid_deg, None, notes)
