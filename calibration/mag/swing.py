"""Heading-deviation ("swing") fit: δψ = A + B·sinψ + C·cosψ + D·sin2ψ + E·cos2ψ.

The classical compass deviation card (NGA Pub. 226, "Handbook of Magnetic Compass Adjustment"; Nourmohammadi &
Sabet, "Back-stepping calibration algorithm for three-axial magnetometer ...", J. of Control 16(3), 2022 —
"the paper" below — §5, eqs. 19–21 and 31): after the field-domain
calibration, the remaining heading error is a truncated Fourier series of the magnetometer heading ψ̂:

    δψ = ψ_ref − ψ̂_mag           (the paper's eq. 21)
    ψ_M = ψ̂_M + A + B sinψ̂ + C cosψ̂ + D sin2ψ̂ + E cos2ψ̂   (the paper's eq. 31)

A is the constant offset (sensor/hull yaw misalignment, asymmetric soft iron): no attitude-independent field
fit can see it (it leaves the field magnitude and the vertical component unchanged), a heading reference can. B, C are semicircular (residual hard iron,
vertical soft iron × Z), D, E quadrantal (horizontal soft iron).

Heading references:
- known headings (a compass-swing table, CSV `reference_deg,compass_deg`), e.g. the eight cardinal and
  intercardinal headings of a classical swing;
- GNSS course over ground, delayed by the receiver latency (the paper's §7.4 used 2 s), used only while the
  speed is sufficient and the track is straight (course ≠ heading in turns and with crab/sideslip).

All angles here are degrees (the paper's coefficients are radians: multiply by 180/π to compare).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ahrsd.core.angles import wrap_180_deg

PAPER_GNSS_DELAY_S = 2.0        # the paper's §7.4: GPS track-angle delay assumed in the field test
DEFAULT_MIN_SPEED_M_S = 1.0     # below this GNSS course is noise (our choice: ~2 kn)
DEFAULT_MAX_TURN_RATE_DEG_S = 1.0  # "straight track" gate on the course rate (our choice)
MIN_SAMPLES = 8                 # a classical swing uses 8 headings (Pub. 226)
MIN_HEADING_SPAN_DEG = 180.0    # B..E need headings spread over the circle
MIN_SECTORS = 5                 # …in at least 5 of the 8 45° sectors (two opposite legs do not determine B..E)


class SwingTableError(ValueError):
    """A compass-swing table file that cannot be read, with the reason and the line."""


class SwingFitError(ValueError):
    """The headings cannot determine the deviation coefficients (too few, one heading, ...)."""


@dataclass(frozen=True)
class DeviationCoefficients:
    """A..E in degrees (δψ = ψ_ref − ψ_mag as a function of ψ_mag). `rms_before_deg`/`rms_after_deg`: RMS
    of δψ before and after correction on the fit data; `a_only_deg`: A fitted alone (the paper's §5 sanity
    value: a large difference to A means the deviation fit is suspect); `n`: samples used."""

    a_deg: float
    b_deg: float
    c_deg: float
    d_deg: float
    e_deg: float
    rms_before_deg: float = math.nan
    rms_after_deg: float = math.nan
    a_only_deg: float = math.nan
    n: int = 0

    def as_array(self) -> np.ndarray:
        return np.array([self.a_deg, self.b_deg, self.c_deg, self.d_deg, self.e_deg])

    def deviation_deg(self, heading_mag_deg):
        """δψ at magnetometer heading(s) ψ̂ (degrees); a float for a scalar heading."""
        h = np.asarray(heading_mag_deg, dtype=np.float64)
        out = (_regressors(h) @ self.as_array()).reshape(h.shape)
        return float(out) if out.ndim == 0 else out

    def apply(self, heading_mag_deg):
        """Corrected heading ψ̂ + δψ(ψ̂) in [0, 360) (the paper's eq. 31); a float for a scalar heading."""
        h = np.asarray(heading_mag_deg, dtype=np.float64)
        out = (h + self.deviation_deg(h)) % 360.0
        return float(out) if np.ndim(out) == 0 else out

    def to_dict(self) -> dict:
        return {"A_deg": self.a_deg, "B_deg": self.b_deg, "C_deg": self.c_deg, "D_deg": self.d_deg,
                "E_deg": self.e_deg, "A_only_deg": self.a_only_deg, "rms_before_deg": self.rms_before_deg,
                "rms_after_deg": self.rms_after_deg, "n": self.n}

    @classmethod
    def zero(cls) -> "DeviationCoefficients":
        return cls(0.0, 0.0, 0.0, 0.0, 0.0)


def _regressors(heading_deg) -> np.ndarray:
    """Rows [1, sinψ, cosψ, sin2ψ, cos2ψ] (the paper's eq. 20)."""
    p = np.radians(np.asarray(heading_deg, dtype=np.float64)).reshape(-1)
    return np.column_stack((np.ones_like(p), np.sin(p), np.cos(p), np.sin(2 * p), np.cos(2 * p)))


def fit_deviation(heading_mag_deg, heading_ref_deg, weights=None) -> DeviationCoefficients:
    """Least-squares A..E (the paper's eq. 20) from magnetometer headings and reference headings (both in the
    same north: subtract the declination from a true reference first, or add it to the magnetic heading).
    Raises SwingFitError when the headings cannot determine the five coefficients."""
    hm = np.asarray(heading_mag_deg, dtype=np.float64).reshape(-1)
    hr = np.asarray(heading_ref_deg, dtype=np.float64).reshape(-1)
    if hm.shape != hr.shape:
        raise SwingFitError(f"{hm.size} magnetometer headings but {hr.size} reference headings")
    ok = np.isfinite(hm) & np.isfinite(hr)
    w = np.ones_like(hm) if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
    ok &= np.isfinite(w) & (w > 0)
    hm, hr, w = hm[ok], hr[ok], w[ok]
    if hm.size < MIN_SAMPLES:
        raise SwingFitError(f"only {hm.size} usable heading pairs; a swing needs at least {MIN_SAMPLES} "
                            "spread over the circle (e.g. the 8 cardinal and intercardinal headings)")
    sectors = np.unique(np.floor((hm % 360.0) / 45.0)).size
    if sectors < MIN_SECTORS:
        raise SwingFitError(f"the headings fall in only {sectors} of the 8 45° sectors; B..E need at least "
                            f"{MIN_SECTORS} (a swing visits N, NE, E, …). Fit A alone with fit_offset()")
    span = heading_span_deg(hm)
    if span < MIN_HEADING_SPAN_DEG:
        raise SwingFitError(f"the headings span only {span:.0f}° of the circle; B..E need headings all "
                            f"round (at least {MIN_HEADING_SPAN_DEG:.0f}°). Fit A alone with fit_offset()")
    dpsi = wrap_180_deg(hr - hm)
    phi = _regressors(hm)
    sw = np.sqrt(w)
    coef, *_ = np.linalg.lstsq(phi * sw[:, None], dpsi * sw, rcond=None)
    if np.linalg.cond(phi * sw[:, None]) > 1e6:
        raise SwingFitError("the heading regressors are singular (headings too clustered)")
    after = wrap_180_deg(dpsi - phi @ coef)
    a_only = float(np.average(dpsi, weights=w))
    return DeviationCoefficients(*map(float, coef), rms_before_deg=float(np.sqrt(np.mean(dpsi**2))),
                                 rms_after_deg=float(np.sqrt(np.mean(after**2))), a_only_deg=a_only,
                                 n=int(hm.size))


def fit_offset(heading_mag_deg, heading_ref_deg) -> DeviationCoefficients:
    """A alone (B..E = 0): the the paper §5 first step, and all one heading (a fixed-yaw calibration) can give."""
    hm = np.asarray(heading_mag_deg, dtype=np.float64).reshape(-1)
    hr = np.asarray(heading_ref_deg, dtype=np.float64).reshape(-1)
    ok = np.isfinite(hm) & np.isfinite(hr)
    if not ok.any():
        raise SwingFitError("no usable heading pairs")
    dpsi = wrap_180_deg(hr[ok] - hm[ok])
    # circular mean, so offsets near ±180° average correctly
    a = math.degrees(math.atan2(np.mean(np.sin(np.radians(dpsi))), np.mean(np.cos(np.radians(dpsi)))))
    return DeviationCoefficients(a, 0.0, 0.0, 0.0, 0.0, rms_before_deg=float(np.sqrt(np.mean(dpsi**2))),
                                 rms_after_deg=float(np.sqrt(np.mean(wrap_180_deg(dpsi - a) ** 2))), a_only_deg=a,
                                 n=int(ok.sum()))


def heading_span_deg(heading_deg) -> float:
    """The smallest arc containing all headings (360 minus the largest gap)."""
    h = np.sort(np.asarray(heading_deg, dtype=np.float64) % 360.0)
    if h.size == 0:
        return 0.0
    gaps = np.diff(np.concatenate((h, [h[0] + 360.0])))
    return float(360.0 - gaps.max())


def pub226_eight_point(deviation_deg_at: dict[str, float]) -> DeviationCoefficients:
    """The classical approximate coefficients from deviations on the 8 headings N, NE, E, SE, S, SW, W, NW
    (NGA Pub. 226 ch. V): A = mean, B = (E − W)/2, C = (N − S)/2,
    D = (NE + SW − SE − NW)/4, E = (N + S − E − W)/4. Deviations east positive."""
    d = deviation_deg_at
    vals = [d[k] for k in ("N", "NE", "E", "SE", "S", "SW", "W", "NW")]
    return DeviationCoefficients(float(np.mean(vals)), (d["E"] - d["W"]) / 2, (d["N"] - d["S"]) / 2,
                                 (d["NE"] + d["SW"] - d["SE"] - d["NW"]) / 4, (d["N"] + d["S"] - d["E"] - d["W"]) / 4,
                                 n=8)


# ------------------------------------------------------------------------------------- heading references


def gnss_course_reference(t_s, course_deg, speed_m_s, *, delay_s: float = PAPER_GNSS_DELAY_S,
                          min_speed_m_s: float = DEFAULT_MIN_SPEED_M_S,
                          max_turn_rate_deg_s: float = DEFAULT_MAX_TURN_RATE_DEG_S,
                          straight_window_s: float = 10.0, at_t_s=None) -> np.ndarray:
    """A heading reference (degrees, NaN where unusable) from GNSS course over ground.

    The receiver reports the course `delay_s` late, so the course stamped t + delay describes the vehicle
    at t (the paper §7.4). A sample is usable only if the speed is at least `min_speed_m_s` and the course rate
    stays below `max_turn_rate_deg_s` over ±straight_window_s/2 (a straight track: in turns and with
    sideslip course ≠ heading). `at_t_s` (default t_s): the times to produce the reference for (e.g. the
    magnetometer sample times). Course is true (geographic) north."""
    t = np.asarray(t_s, dtype=np.float64).reshape(-1)
    c = np.asarray(course_deg, dtype=np.float64).reshape(-1)
    v = np.asarray(speed_m_s, dtype=np.float64).reshape(-1)
    if not (t.size == c.size == v.size):
        raise ValueError("t_s, course_deg and speed_m_s must have the same length")
    at = t if at_t_s is None else np.asarray(at_t_s, dtype=np.float64).reshape(-1)
    if t.size < 2:
        return np.full(at.shape, np.nan)
    good = np.isfinite(c) & np.isfinite(v) & (v >= min_speed_m_s)
    unwrapped = np.degrees(np.unwrap(np.radians(np.where(np.isfinite(c), c, 0.0))))
    # straight: the mean course rate over the window around each fix (a mean, so fix-to-fix course noise
    # does not read as turning) stays below the limit, and every fix in the window is usable
    half = straight_window_s / 2.0
    lo = np.searchsorted(t, t - half, side="left")
    hi = np.searchsorted(t, t + half, side="right")
    span = t[hi - 1] - t[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        rate = np.where(span > 0, (unwrapped[hi - 1] - unwrapped[lo]) / span, np.inf)
    csum = np.concatenate(([0], np.cumsum(~good)))
    straight = ((csum[hi] - csum[lo]) == 0) & (np.abs(rate) <= max_turn_rate_deg_s)
    usable = good & straight
    # the reference for time τ is the course stamped τ + delay
    query = at + delay_s
    out = np.interp(query, t, unwrapped) % 360.0
    idx = np.clip(np.searchsorted(t, query), 1, t.size - 1)
    nearest_ok = usable[idx] & usable[idx - 1]
    inside = (query >= t[0]) & (query <= t[-1])
    return np.where(nearest_ok & inside, out, np.nan)


def load_swing_table(path) -> tuple[np.ndarray, np.ndarray]:
    """Read a compass-swing table: CSV with a header naming a reference column (`reference_deg`,
    `heading_ref_deg`, `true_deg` or `known_deg`) and a compass column (`compass_deg`, `heading_mag_deg`
    or `measured_deg`); '#' comment lines allowed. Returns (reference_deg, compass_deg).
    Raises SwingTableError naming the line on any malformed entry."""
    ref_names = ("reference_deg", "heading_ref_deg", "true_deg", "known_deg")
    mag_names = ("compass_deg", "heading_mag_deg", "measured_deg")
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise SwingTableError(f"{p}: cannot read the swing table ({exc})") from None
    lines = [(i + 1, ln) for i, ln in enumerate(text.splitlines()) if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise SwingTableError(f"{p}: empty swing table")
    header = [h.strip().lower() for h in next(csv.reader([lines[0][1]]))]
    ref_col = next((header.index(n) for n in ref_names if n in header), None)
    mag_col = next((header.index(n) for n in mag_names if n in header), None)
    if ref_col is None or mag_col is None:
        raise SwingTableError(f"{p}:{lines[0][0]}: header {header} must name a reference column "
                              f"({'/'.join(ref_names)}) and a compass column ({'/'.join(mag_names)})")
    ref, mag = [], []
    for lineno, row in zip((ln for ln, _ in lines[1:]), csv.reader([ln for _, ln in lines[1:]])):
        try:
            r, m = float(row[ref_col]), float(row[mag_col])
        except (IndexError, ValueError):
            raise SwingTableError(f"{p}:{lineno}: expected numbers in columns {header[ref_col]!r} and "
                                  f"{header[mag_col]!r}, got {row}") from None
        if not (math.isfinite(r) and math.isfinite(m)) or not (-360.0 <= r <= 720.0 and -360.0 <= m <= 720.0):
            raise SwingTableError(f"{p}:{lineno}: heading out of range: {row}")
        ref.append(r % 360.0)
        mag.append(m % 360.0)
    if len(ref) < 1:
        raise SwingTableError(f"{p}: no rows after the header")
    return np.array(ref), np.array(mag)


def fit_swing_table(path) -> DeviationCoefficients:
    """The deviation card from a compass-swing table file (`load_swing_table`): A..E when the headings go
    all round (≥ 8 of them), A alone otherwise. Both columns must use the same north (magnetic reference
    headings, or a true reference minus the declination)."""
    ref, mag = load_swing_table(path)
    try:
        return fit_deviation(mag, ref)
    except SwingFitError:
        return fit_offset(mag, ref)


# A of the full fit and A alone differ by more than this when the headings are too few or bunched together
A_AGREEMENT_DEG = 1.0


def fit_deviation_card(heading_deg, reference_deg, reference_name: str = "swing headings") -> tuple[
        DeviationCoefficients, dict]:
    """The card A..E of `heading_deg` against `reference_deg` and its report: the card's to_dict(), a "note"
    when the headings could give A only, a "warning" when A of the full fit and A alone disagree (headings
    too few or bunched). Raises SwingFitError when not even A can be fitted."""
    rep: dict = {}
    try:
        card = fit_deviation(heading_deg, reference_deg)
    except SwingFitError as exc:
        card = fit_offset(heading_deg, reference_deg)
        rep["note"] = f"A only: {exc}"
    rep.update(card.to_dict())
    if math.isfinite(card.a_only_deg) and abs(card.a_deg - card.a_only_deg) > A_AGREEMENT_DEG:
        rep["warning"] = (f"A of the full fit ({card.a_deg:.2f}°) differs from A alone ({card.a_only_deg:.2f}°): the "
                          f"{reference_name} are too few or unevenly spread (the back-stepping paper's §5 check)")
    return card, rep
