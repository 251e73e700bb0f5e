"""The back-stepping magnetometer calibration as published: Nourmohammadi & Sabet, "Back-stepping calibration
algorithm for three-axial magnetometer applied to autonomous underwater vehicles with magnetic deviations",
Journal of Control (K.N. Toosi University of Technology) 16(3), 71–82, 2022 ("the paper" below).

The paper calibrates an AUV's magnetometer in three stages:

1. a conventional axis-aligned sphere fit (eqs. 11–17: the linear regression Ĥx² = Φ·x and the algebraic
   recovery of b and s) on whatever rotation the vehicle allows;
2. levelling of the calibrated field with the AHRS roll/pitch (eq. 23), split into the horizontal intensity
   H_h (eq. 24) and the vertical component H_z;
3. "back-stepping": corrective passes on an out-and-back run that (i) rescale s_x, s_y so the mean H_h equals
   the reference (IGRF/WMM), (ii) change s_z to remove the step of |H| between the legs and (iii) change b_z
   so |H| equals the reference (eqs. 29–30); repeated until the step vanishes (Tables 3–6).

Here (ii)+(iii) are solved in closed form (ahrsd's own; the paper iterates them), extended to tilted legs (the
levelled vertical component is linear in u = 1/s_z and v = b_z/s_z), with a stopping rule and a per-pass report:
`backstep_correct`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ahrsd.core.angles import tilt_compensated_heading_rad, wrap_pi

from ..models import MagModel
from .observability import level_vectors

PAPER_STEP_TOL_UT = 0.02         # the paper's Table 6 / Fig. 12: final out-and-back step 20 nT


class BacksteppingError(ValueError):
    """Inputs the back-stepping calibration cannot work with (shapes, missing attitude)."""


@dataclass(frozen=True)
class DiagonalModel:
    """The paper's eq. 11/18: calibrated = (raw − b)/s per axis. b in raw units (µT here), s dimensionless."""

    bias: np.ndarray
    scale: np.ndarray

    def apply(self, raw: np.ndarray) -> np.ndarray:
        return (np.asarray(raw, dtype=np.float64) - self.bias) / self.scale

    def to_mag_model(self) -> MagModel:
        return MagModel(np.asarray(self.bias, dtype=np.float64), np.diag(1.0 / np.asarray(self.scale)))

    def replace(self, **kw) -> "DiagonalModel":
        b, s = np.array(self.bias, dtype=np.float64), np.array(self.scale, dtype=np.float64)
        for i, ax in enumerate("xyz"):
            if f"b{ax}" in kw:
                b[i] = kw[f"b{ax}"]
            if f"s{ax}" in kw:
                s[i] = kw[f"s{ax}"]
        return DiagonalModel(b, s)


@dataclass(frozen=True)
class SphereFit:
    """Result of the paper's eq. 12–17 regression. `x` = [bx, (sx/sy)², (sx/sy)²·by, (sx/sz)², (sx/sz)²·bz,
    sx²H² − bx² − (sx/sy)²by² − (sx/sz)²bz²] (in coordinates centred on `origin`). `model` is None and
    `reason` says why when the coefficients are not physical (negative ratios or radicand: "unrealistic,
    even complex coefficients", the paper's §5, test 1)."""

    model: DiagonalModel | None
    x: np.ndarray
    origin: np.ndarray
    condition_number: float
    reason: str | None = None


def sphere_fit_paper(raw: np.ndarray, field_ut: float) -> SphereFit:
    """Axis-aligned ellipsoid ("sphere") fit of the paper's eqs. 12–17 by ordinary least squares.

    z_k = Ĥx,k², Φ_k = [2Ĥx, −Ĥy², 2Ĥy, −Ĥz², 2Ĥz, 1] (eq. 13–14), x̂ = (ΦᵀΦ)⁻¹Φᵀz (eq. 16), then
    bx = x1, by = x3/x2, bz = x5/x4, sx = √((x6 + x1² + x3²/x2 + x5²/x4)/H²), sy = sx/√x2, sz = sx/√x4 (eq. 17).
    The regression runs on data centred on their mean (same algebra, better conditioned); b is shifted back."""
    m = np.asarray(raw, dtype=np.float64)
    origin = m.mean(axis=0)
    c = m - origin
    hx, hy, hz = c[:, 0], c[:, 1], c[:, 2]
    phi = np.column_stack((2 * hx, -hy**2, 2 * hy, -hz**2, 2 * hz, np.ones_like(hx)))
    z = hx**2
    col = np.linalg.norm(phi, axis=0)
    col[col == 0] = 1.0
    sv = np.linalg.svd(phi / col, compute_uv=False)
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf
    x, *_ = np.linalg.lstsq(phi, z, rcond=None)
    x1, x2, x3, x4, x5, x6 = x
    if not np.all(np.isfinite(x)) or x2 <= 0 or x4 <= 0:
        return SphereFit(None, x, origin, cond, f"non-physical axis ratios (sx/sy)² = {x2:.3g}, (sx/sz)² = "
                         f"{x4:.3g}: the data lack rotation about enough axes (the paper's §5, test 1)")
    radicand = (x6 + x1**2 + x3**2 / x2 + x5**2 / x4) / field_ut**2
    if not radicand > 0:
        return SphereFit(None, x, origin, cond, f"negative radicand {radicand:.3g} for sx²: complex coefficients "
                         "(the paper's §5, test 1: data without rich rotation)")
    sx = math.sqrt(radicand)
    b = np.array([x1, x3 / x2, x5 / x4]) + origin
    s = np.array([sx, sx / math.sqrt(x2), sx / math.sqrt(x4)])
    return SphereFit(DiagonalModel(b, s), x, origin, cond)


def horizontal_vertical(levelled_ut: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """H_h = √(Hx² + Hy²) (eq. 24) and H_z (down positive) of levelled vectors."""
    v = np.asarray(levelled_ut, dtype=np.float64)
    return np.hypot(v[:, 0], v[:, 1]), v[:, 2]


def magnetic_heading_deg(calibrated_ut: np.ndarray, roll_rad, pitch_rad) -> np.ndarray:
    """Tilt-compensated magnetic heading (the paper's eqs. 7–8, ψ = atan2(−M2, M1)) in [0, 360) degrees."""
    return np.degrees(tilt_compensated_heading_rad(calibrated_ut, roll_rad, pitch_rad)) % 360.0


# ------------------------------------------------------------------------ the corrective steps (the paper's §5)


def scale_horizontal(sx: float, sy: float, hh_measured: float, hh_reference: float) -> tuple[float, float]:
    """Corrective step 1: sx, sy ← sx·(H_h,meas/H_h,ref), sy·(…), so the mean horizontal intensity equals the
    reference (the paper's §5; Table 3: 0.19556·27999/27451 = 0.19947)."""
    k = hh_measured / hh_reference
    return sx * k, sy * k


def rescale_vertical(hz: float, sz_old: float, sz_new: float) -> float:
    """H_z after changing s_z with the raw reading fixed: H_z' = H_z·s_z,old/s_z,new (Table 3 → 4:
    38810·0.16142/0.20642 = 30349)."""
    return hz * sz_old / sz_new


def solve_vertical_bias(z_raw_mean: float, sz: float, total: float, hh: float) -> float:
    """Corrective step 3 (eq. 29–30): H_h² + ((Ĥz − b_z)/s_z)² = H² ⇒ b_z = Ĥz − s_z·√(H² − H_h²), root with
    H_z > 0 (downward field, northern hemisphere; pass a negative `sz`-free form for the south: see
    `solve_vertical_bias_signed`). Paper: 5362 − 0.20642·√(48752² − 27450²) = −2955."""
    return solve_vertical_bias_signed(z_raw_mean, sz, total, hh, 1.0)


def solve_vertical_bias_signed(z_raw_mean: float, sz: float, total: float, hh: float, hz_sign: float) -> float:
    if total < hh:
        raise BacksteppingError(f"horizontal intensity {hh:.4g} exceeds the total {total:.4g}: no vertical root")
    return z_raw_mean - sz * math.copysign(math.sqrt(total**2 - hh**2), hz_sign)


def closed_form_vertical(z_out: float, z_ret: float, hh_out: float, hh_ret: float, total: float,
                         hz_sign: float = 1.0) -> tuple[float, float]:
    """Closed form of corrective steps (ii)+(iii) for level legs (the paper iterates them):
    both legs must read |H| = H_ref, (z_L − b_z)/s_z = V_L = ±√(H² − H_h,L²), so s_z = (z_o − z_r)/(V_o − V_r)
    and b_z = z_o − s_z·V_o. Raises when the legs carry no information on s_z
    (equal vertical readings or equal horizontal intensities)."""
    v_out = math.copysign(math.sqrt(total**2 - hh_out**2), hz_sign)
    v_ret = math.copysign(math.sqrt(total**2 - hh_ret**2), hz_sign)
    if v_out == v_ret or z_out == z_ret:
        raise BacksteppingError("the legs have the same vertical reading or horizontal intensity: s_z is not "
                                "determined by them (use legs on different headings)")
    sz = (z_out - z_ret) / (v_out - v_ret)
    return sz, z_out - sz * v_out


# ---------------------------------------------------------------------------------------- legs and steps


def segment_legs(t_s: np.ndarray, heading_deg: np.ndarray, *, min_duration_s: float = 60.0,
                 max_spread_deg: float = 8.0, window_s: float = 20.0) -> np.ndarray:
    """Label straight legs: runs of at least `min_duration_s` where the heading stays within ±max_spread_deg
    of the run's circular mean over a sliding `window_s`. Returns int labels (n,), −1 outside legs."""
    t = np.asarray(t_s, dtype=np.float64)
    h = np.radians(np.asarray(heading_deg, dtype=np.float64))
    n = t.size
    labels = np.full(n, -1, dtype=int)
    if n < 3:
        return labels
    c, s = np.cos(h), np.sin(h)
    cc, cs = np.concatenate(([0.0], np.cumsum(c))), np.concatenate(([0.0], np.cumsum(s)))
    lo = np.searchsorted(t, t - window_s / 2)
    hi = np.searchsorted(t, t + window_s / 2, side="right")
    cnt = np.maximum(hi - lo, 1)
    mc, ms = (cc[hi] - cc[lo]) / cnt, (cs[hi] - cs[lo]) / cnt
    resultant = np.hypot(mc, ms)
    # circular spread: R = cos(spread) for a two-point spread; cheap and monotone
    steady = resultant > math.cos(math.radians(max_spread_deg))
    mean_dir = np.arctan2(ms, mc)
    label = 0
    i = 0
    while i < n:
        if not steady[i]:
            i += 1
            continue
        j = i
        while j + 1 < n and steady[j + 1] and abs(float(wrap_pi(mean_dir[j + 1] - mean_dir[i]))) < math.radians(max_spread_deg):
            j += 1
        if t[j] - t[i] >= min_duration_s:
            labels[i:j + 1] = label
            label += 1
        i = j + 1
    return labels


@dataclass(frozen=True)
class LegStats:
    label: int
    n: int
    heading_deg: float
    hh_ut: float
    hz_ut: float
    total_ut: float


def leg_statistics(calibrated_ut: np.ndarray, roll_rad, pitch_rad, legs: np.ndarray) -> list[LegStats]:
    """Mean horizontal/vertical/total intensity and circular-mean heading per leg label (≥ 0)."""
    lv = level_vectors(calibrated_ut, roll_rad, pitch_rad)
    hh, hz = horizontal_vertical(lv)
    tot = np.linalg.norm(calibrated_ut, axis=1)
    psi = np.arctan2(-lv[:, 1], lv[:, 0])
    out = []
    for lab in np.unique(legs[legs >= 0]):
        k = legs == lab
        head = math.degrees(math.atan2(np.mean(np.sin(psi[k])), np.mean(np.cos(psi[k])))) % 360.0
        out.append(LegStats(int(lab), int(k.sum()), head, float(hh[k].mean()), float(hz[k].mean()),
                            float(tot[k].mean())))
    return out


def inter_leg_step_ut(stats: list[LegStats]) -> float:
    """The largest difference of mean |H| between legs (the paper's out-and-back "step")."""
    if len(stats) < 2:
        return math.nan
    tot = [s.total_ut for s in stats]
    return float(max(tot) - min(tot))


# ------------------------------------------------------------------------------- back-stepping corrective loop


@dataclass(frozen=True)
class BackstepPass:
    """One corrective pass (steps 1–3) of the back-stepping loop."""

    index: int
    bias: tuple
    scale: tuple
    hh_ut: float
    hz_ut: float
    total_ut: float
    step_ut: float        # NaN with a single leg
    sz_source: str        # "closed-form" or "kept (legs do not determine s_z)"

    def to_dict(self) -> dict:
        return {"pass": self.index, "b": list(self.bias), "s": list(self.scale), "hh_ut": self.hh_ut,
                "hz_ut": self.hz_ut, "total_ut": self.total_ut,
                "step_ut": self.step_ut if math.isfinite(self.step_ut) else None,   # None: a single leg
                "sz_source": self.sz_source}


@dataclass(frozen=True)
class BackstepResult:
    model: DiagonalModel
    passes: list
    converged: bool
    stop_reason: str
    step_before_ut: float
    step_after_ut: float


def _levelled_vertical_terms(raw, model: DiagonalModel, roll, pitch):
    """Split the levelled vertical component into k + u·(cϕcθ·Ĥz) − v·cϕcθ with u = 1/s_z, v = b_z/s_z."""
    cal = model.apply(raw)
    sr, cr, sp, cp = np.sin(roll), np.cos(roll), np.sin(pitch), np.cos(pitch)
    k = -sp * cal[:, 0] + cp * sr * cal[:, 1]
    g = cp * cr
    return k, g * raw[:, 2], g


def backstep_correct(raw: np.ndarray, roll_rad, pitch_rad, legs: np.ndarray, initial: DiagonalModel,
                     hh_ref_ut: float, hz_ref_ut: float, *, step_tol_ut: float = PAPER_STEP_TOL_UT,
                     field_tol_ut: float = PAPER_STEP_TOL_UT, max_passes: int = 10) -> BackstepResult:
    """The paper's corrective loop on multi-leg data (labels ≥ 0 in `legs`, −1 ignored).

    Each pass: (1) sx, sy ← sx, sy·mean(H_h)/H_h,ref over all leg samples; (2+3) s_z and b_z in closed form
    so that the mean levelled vertical component of each leg equals V_L = ±√(H² − H_h,L²) (exact with tilt:
    linear least squares in u = 1/s_z, v = b_z/s_z over the legs). When the legs cannot determine s_z (same
    vertical reading), s_z is kept and only b_z is solved (the paper's step 3). Stops when the inter-leg step
    and |mean |H| − H_ref| are both within tolerance, when a pass changes nothing, or after max_passes."""
    raw = np.asarray(raw, dtype=np.float64)
    roll, pitch = np.asarray(roll_rad, dtype=np.float64), np.asarray(pitch_rad, dtype=np.float64)
    legs = np.asarray(legs)
    use = legs >= 0
    if not use.any():
        raise BacksteppingError("no samples on a leg (labels ≥ 0)")
    raw, roll, pitch, legs = raw[use], roll[use], pitch[use], legs[use]
    labels = np.unique(legs)
    total_ref = math.hypot(hh_ref_ut, hz_ref_ut)
    sign = 1.0 if hz_ref_ut >= 0 else -1.0
    model = initial
    step_before = inter_leg_step_ut(leg_statistics(model.apply(raw), roll, pitch, legs))
    passes: list[BackstepPass] = []
    converged, reason = False, f"max_passes={max_passes} reached"
    for it in range(1, max_passes + 1):
        prev = model
        # step 1: horizontal scale
        hh, _ = horizontal_vertical(level_vectors(model.apply(raw), roll, pitch))
        sx, sy = scale_horizontal(model.scale[0], model.scale[1], float(hh.mean()), hh_ref_ut)
        model = model.replace(sx=sx, sy=sy)
        # steps 2+3: vertical scale and bias per leg
        model, source = _vertical_scale_and_bias(model, raw, roll, pitch, legs, labels, total_ref, sign)
        record, field_err = _pass_record(it, model, raw, roll, pitch, legs, source, total_ref)
        passes.append(record)
        step = record.step_ut
        if (not math.isfinite(step) or step <= step_tol_ut) and field_err <= field_tol_ut:
            converged, reason = True, f"step {0.0 if not math.isfinite(step) else step * 1000:.1f} nT ≤ " \
                                      f"{step_tol_ut * 1000:.0f} nT and field within {field_tol_ut * 1000:.0f} nT"
            break
        change = np.max(np.abs(np.concatenate((model.bias - prev.bias, (model.scale - prev.scale) / prev.scale * 100))))
        if change < 1e-9:
            reason = "a pass changed nothing: the legs cannot reduce the step further"
            break
    step_after = passes[-1].step_ut if passes else step_before
    return BackstepResult(model, passes, converged, reason, step_before, step_after)


def _vertical_scale_and_bias(model: DiagonalModel, raw, roll, pitch, legs, labels, total_ref: float, sign: float
                             ) -> tuple[DiagonalModel, str]:
    """The paper's steps 2+3: s_z and b_z in closed form so that the mean levelled vertical component of each leg
    equals V_L = ±√(H² − H_h,L²) (linear least squares in u = 1/s_z, v = b_z/s_z over the legs); when the legs
    cannot determine s_z (their vertical readings or targets do not differ measurably, or the solution is not
    plausible) s_z is kept and only b_z is solved (step 3). Returns the model and how s_z was found."""
    hh, _ = horizontal_vertical(level_vectors(model.apply(raw), roll, pitch))
    k, gz, g = _levelled_vertical_terms(raw, model, roll, pitch)
    rows, rhs = [], []
    for lab in labels:
        sel = legs == lab
        v_l = math.copysign(math.sqrt(max(total_ref**2 - float(hh[sel].mean()) ** 2, 0.0)), sign)
        rows.append([gz[sel].mean(), -g[sel].mean()])
        rhs.append(v_l - k[sel].mean())
    a, b = np.array(rows), np.array(rhs)
    source = "closed-form"
    spread_z = np.ptp(a[:, 0]) * abs(1.0 / model.scale[2]) if len(labels) > 1 else 0.0
    spread_v = float(np.ptp(b)) if len(labels) > 1 else 0.0
    uv = None
    if len(labels) > 1 and spread_z > 0.05 and spread_v > 0.05:   # µT: legs differ measurably
        uv, *_ = np.linalg.lstsq(a, b, rcond=None)
        if not (uv[0] > 0 and 0.1 < (1 / uv[0]) / model.scale[2] < 10):
            uv = None
    if uv is None:
        source = "kept (legs do not determine s_z)"
        u = 1.0 / model.scale[2]
        v = float(np.sum(a[:, 1] * (b - a[:, 0] * u)) / np.sum(a[:, 1] ** 2))   # b_z alone (paper step 3)
        uv = np.array([u, v])
    sz = 1.0 / uv[0]
    return model.replace(sz=sz, bz=uv[1] * sz), source


def _pass_record(it: int, model: DiagonalModel, raw, roll, pitch, legs, source: str, total_ref: float
                 ) -> tuple["BackstepPass", float]:
    """What a pass left: the model, the mean levelled horizontal and vertical field, the mean |H|, the inter-leg
    step; and |H of the mean levelled field − H_ref| (µT)."""
    stats = leg_statistics(model.apply(raw), roll, pitch, legs)
    step = inter_leg_step_ut(stats)
    cal = model.apply(raw)
    lv = level_vectors(cal, roll, pitch)
    hh_all, hz_all = horizontal_vertical(lv)
    tot = float(np.linalg.norm(cal, axis=1).mean())
    record = BackstepPass(it, tuple(map(float, model.bias)), tuple(map(float, model.scale)),
                          float(hh_all.mean()), float(hz_all.mean()), tot, step, source)
    return record, abs(math.hypot(hh_all.mean(), hz_all.mean()) - total_ref)
