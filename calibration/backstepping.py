"""Back-stepping magnetometer calibration for vehicles that cannot be tumbled (seed 002), and its
generalised vertical-channel form.

Seed 002 (Nourmohammadi & Sabet 2022) calibrates an AUV's magnetometer in three stages:

1. a conventional axis-aligned sphere fit (eqs. 11–17: the linear regression Ĥx² = Φ·x and the algebraic
   recovery of b and s) on whatever rotation the vehicle allows;
2. levelling of the calibrated field with the AHRS roll/pitch (eq. 23), split into the horizontal intensity
   H_h (eq. 24) and the vertical component H_z;
3. "back-stepping": corrective passes on an out-and-back run that (i) rescale s_x, s_y so the mean H_h equals
   the reference (IGRF/WMM), (ii) change s_z to remove the step of |H| between the legs and (iii) change b_z
   so |H| equals the reference (eq. 29–30); repeated until the step vanishes (1400 → 600 → 20 nT, Tables 3–6).

Here (ii)+(iii) are solved in closed form (seed 002 §6.4, extended to tilted legs: the levelled vertical
component is linear in u = 1/s_z and v = b_z/s_z), with a stopping rule and a per-pass report:
`backstep_correct`.

The generalised form for real vehicles (`fit_vertical_channel`) imposes the same two conditions — the field
magnitude equals the WMM total intensity and the levelled vertical component equals the WMM vertical
intensity — on every sample at once, with a full 3×3 soft-iron matrix, by least squares. Levelling uses
roll/pitch, so the vertical component depends on how each axis responds to the vertical field: this is what
pins the z hard iron and z scale (and the whole vertical soft-iron column) that an ellipsoid fit cannot see
on data with only ±2…±10° of tilt. Without a known position, the dip angle is a free parameter (needs ≥ ±5°
of tilt). A constant heading offset (sensor yaw misalignment, "coefficient A") is only weakly visible through
tilt; with a heading reference (GNSS course, known headings) it is fitted (`swing.py`) and folded into the
soft-iron matrix.

`fit_backstepping(data, reference, **options)` is the `fit_mag("backstepping", ...)` entry point;
`plot_backstepping(result, data, path)` draws the report figure.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from .magfit import MagFitInput, MagFitResult, finite_rows, refuse
from .models import MagModel
from .observability import (assess_support, down_in_body, level_vectors, lowpass, parameter_uncertainty,
                            roll_pitch_from_accel, tilt_statistics)
from . import swing

METHOD = "backstepping"
ADIS16405_MAG_NOISE_UT = 0.125   # ADIS16405 datasheet: magnetometer output noise 1.25 mgauss rms
DEFAULT_TILT_SIGMA_DEG = 0.3     # roll/pitch error of a low-passed accelerometer / AHRS (anchors §0.3)
PAPER_STEP_TOL_UT = 0.02         # seed 002 Table 6 / Fig. 12: final out-and-back step 20 nT
DEFAULT_FIT_RATE_HZ = 10.0       # samples are block-averaged to this rate before fitting
MAX_PREDICTED_HEADING_STD_DEG = 3.0  # refuse when the data leave the heading worse than this (1σ)
PRIOR_SIGMA_SOFT_IRON = 0.5      # weak prior on each soft-iron entry (keeps undetermined directions at the start value)
MAX_FITTED_SPEED_M_S = 15.0      # a fitted centripetal speed above this is not a boat/AUV/rover calibration run
MAX_CENTRIPETAL_LEAN_RAD = 0.2   # …nor a lean into the turn of more than ~11°
DISTURBANCE_SIGMAS = 5.0         # |H| residual beyond this many robust σ: a magnetically disturbed sample
DISTURBED_FRACTION_FOR_ROBUST = 0.01


class BacksteppingError(ValueError):
    """Inputs the back-stepping calibration cannot work with (shapes, missing attitude)."""


class PlotUnavailableError(ImportError):
    """`plot_backstepping` was called but matplotlib (the optional `ahrsd[plot]` extra) is not installed."""


PLOT_INSTALL_HINT = "pip install 'ahrsd[plot]'"


def fold_heading_offset(model: MagModel, offset_deg: float) -> MagModel:
    """The model whose heading is `offset_deg` larger (the deviation coefficient A folded in): heading += A
    ⇔ the calibrated vector rotated by −A about body z, W ← Rz(−A)·W. Magnitude and vertical unchanged."""
    a = math.radians(offset_deg)
    rz = np.array([[math.cos(a), math.sin(a), 0.0], [-math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
    return MagModel(model.hard_iron_ut, rz @ model.soft_iron)


# =========================================================================================== paper algebra


@dataclass(frozen=True)
class DiagonalModel:
    """Seed 002 eq. 11/18: calibrated = (raw − b)/s per axis. b in raw units (µT here), s dimensionless."""

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
    """Result of the seed 002 eq. 12–17 regression. `x` = [bx, (sx/sy)², (sx/sy)²·by, (sx/sz)², (sx/sz)²·bz,
    sx²H² − bx² − (sx/sy)²by² − (sx/sz)²bz²] (in coordinates centred on `origin`). `model` is None and
    `reason` says why when the coefficients are not physical (negative ratios or radicand: "unrealistic,
    even complex coefficients", seed 002 §7.2)."""

    model: DiagonalModel | None
    x: np.ndarray
    origin: np.ndarray
    condition_number: float
    reason: str | None = None


def sphere_fit_paper(raw: np.ndarray, field_ut: float) -> SphereFit:
    """Axis-aligned ellipsoid ("sphere") fit of seed 002 eqs. 12–17 by ordinary least squares.

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
                         f"{x4:.3g}: the data lack rotation about enough axes (seed 002 §7.2)")
    radicand = (x6 + x1**2 + x3**2 / x2 + x5**2 / x4) / field_ut**2
    if not radicand > 0:
        return SphereFit(None, x, origin, cond, f"negative radicand {radicand:.3g} for sx²: complex coefficients "
                         "(seed 002 §7.2: data without rich rotation)")
    sx = math.sqrt(radicand)
    b = np.array([x1, x3 / x2, x5 / x4]) + origin
    s = np.array([sx, sx / math.sqrt(x2), sx / math.sqrt(x4)])
    return SphereFit(DiagonalModel(b, s), x, origin, cond)


def horizontal_vertical(levelled_ut: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """H_h = √(Hx² + Hy²) (eq. 24) and H_z (down positive) of levelled vectors."""
    v = np.asarray(levelled_ut, dtype=np.float64)
    return np.hypot(v[:, 0], v[:, 1]), v[:, 2]


def magnetic_heading_deg(calibrated_ut: np.ndarray, roll_rad, pitch_rad) -> np.ndarray:
    """Tilt-compensated magnetic heading (seed 002 eqs. 7–8, ψ = atan2(−M2, M1)) in [0, 360) degrees."""
    lv = level_vectors(calibrated_ut, roll_rad, pitch_rad)
    return np.degrees(np.arctan2(-lv[:, 1], lv[:, 0])) % 360.0


# ------------------------------------------------------------------------ the corrective steps (seed 002 §5)


def scale_horizontal(sx: float, sy: float, hh_measured: float, hh_reference: float) -> tuple[float, float]:
    """Corrective step 1: sx, sy ← sx·(H_h,meas/H_h,ref), sy·(…), so the mean horizontal intensity equals the
    reference (seed 002 §5; Table 3: 0.19556·27999/27451 = 0.19947)."""
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
    """Seed 002 §6.4 for level legs: both legs must read |H| = H_ref, (z_L − b_z)/s_z = V_L = ±√(H² − H_h,L²),
    so s_z = (z_o − z_r)/(V_o − V_r) and b_z = z_o − s_z·V_o. Raises when the legs carry no information on s_z
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
        while j + 1 < n and steady[j + 1] and abs(_wrap_pi(mean_dir[j + 1] - mean_dir[i])) < math.radians(max_spread_deg):
            j += 1
        if t[j] - t[i] >= min_duration_s:
            labels[i:j + 1] = label
            label += 1
        i = j + 1
    return labels


def _wrap_pi(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


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
    """The largest difference of mean |H| between legs (the seed 002 out-and-back "step")."""
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
    """Seed 002 corrective loop on multi-leg data (labels ≥ 0 in `legs`, −1 ignored).

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
        model = model.replace(sz=sz, bz=uv[1] * sz)
        stats = leg_statistics(model.apply(raw), roll, pitch, legs)
        step = inter_leg_step_ut(stats)
        cal = model.apply(raw)
        lv = level_vectors(cal, roll, pitch)
        hh_all, hz_all = horizontal_vertical(lv)
        tot = float(np.linalg.norm(cal, axis=1).mean())
        passes.append(BackstepPass(it, tuple(map(float, model.bias)), tuple(map(float, model.scale)),
                                   float(hh_all.mean()), float(hz_all.mean()), tot,
                                   step, source))
        field_err = abs(math.hypot(hh_all.mean(), hz_all.mean()) - total_ref)
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


# ===================================================================== generalised vertical-channel fit


@dataclass(frozen=True)
class VerticalChannelFit:
    """calibrated = soft_iron·(raw − hard_iron). `vertical_ut`: the reference or fitted vertical intensity;
    `jacobian` of the whitened data residuals at the solution (for uncertainty); `names` of its columns."""

    soft_iron: np.ndarray
    hard_iron_ut: np.ndarray
    total_ut: float
    vertical_ut: float
    free_dip: bool
    magnitude_rms_ut: float
    vertical_rms_ut: float
    whitened_rms: float
    jacobian: np.ndarray
    names: list
    init: str
    nfev: int
    success: bool
    message: str
    speed_m_s: float | None = None     # fitted forward speed of the centripetal compensation (None: not fitted)


_PARAM_NAMES = [f"soft_iron[{i}{j}]" for i in "xyz" for j in "xyz"] + ["hard_iron_x_ut", "hard_iron_y_ut", "hard_iron_z_ut"]


def _conic_init(raw: np.ndarray, d: np.ndarray, total: float, vertical: float):
    """Start values for level-ish data: a 2-D ellipse through the horizontal components gives the horizontal
    hard iron and soft iron; the vertical row comes from regressing raw z on the calibrated horizontal
    components and on the body-z field implied by the vertical constraint (b·d = H_z)."""
    xy0 = raw[:, :2].mean(axis=0)
    xy = raw[:, :2] - xy0
    a = np.column_stack((xy[:, 0] ** 2, xy[:, 0] * xy[:, 1], xy[:, 1] ** 2, xy[:, 0], xy[:, 1]))
    coef, *_ = np.linalg.lstsq(a, np.ones(xy.shape[0]), rcond=None)
    a2 = np.array([[coef[0], coef[1] / 2], [coef[1] / 2, coef[2]]])
    g = coef[3:5]
    try:
        x0 = -0.5 * np.linalg.solve(a2, g)
    except np.linalg.LinAlgError:
        return None
    k = 1.0 + x0 @ a2 @ x0
    a2n = a2 / k
    ev, evec = np.linalg.eigh(a2n)
    if not np.all(ev > 0):
        return None
    hh = math.sqrt(max(total**2 - vertical**2, 1e-6 * total**2))
    w_h = hh * (evec * np.sqrt(ev)) @ evec.T            # symmetric square root, radius → H_h
    ch = (xy - x0) @ w_h.T
    dz = np.where(np.abs(d[:, 2]) > 0.2, d[:, 2], 0.2)
    bz = (vertical - ch[:, 0] * d[:, 0] - ch[:, 1] * d[:, 1]) / dz
    k0 = 1.0 / float(np.mean(np.linalg.svd(w_h, compute_uv=False)))
    # ridge row: prior k = k0 with σ 30 % against ~0.2 µT data noise (only matters when b_z barely varies)
    lam = 0.2 / (0.3 * k0)
    reg = np.column_stack((ch, bz, np.ones_like(bz)))
    reg = np.vstack((reg, [0.0, 0.0, lam, 0.0]))
    rhs = np.concatenate((raw[:, 2], [lam * k0]))
    zc, *_ = np.linalg.lstsq(reg, rhs, rcond=None)
    dmat = np.zeros((3, 3))
    dmat[:2, :2] = np.linalg.inv(w_h)
    dmat[2] = zc[:3]
    try:
        w0 = np.linalg.inv(dmat)
    except np.linalg.LinAlgError:
        return None
    h0 = np.array([xy0[0] + x0[0], xy0[1] + x0[1], zc[3]])
    return w0, h0


def _ellipsoid_init(raw: np.ndarray, total: float):
    """Start values from an algebraic 10-parameter ellipsoid (only when it is one: positive definite)."""
    c0 = raw.mean(axis=0)
    x = raw - c0
    a = np.column_stack((x[:, 0] ** 2, x[:, 1] ** 2, x[:, 2] ** 2, 2 * x[:, 0] * x[:, 1], 2 * x[:, 0] * x[:, 2],
                         2 * x[:, 1] * x[:, 2], 2 * x[:, 0], 2 * x[:, 1], 2 * x[:, 2], np.ones(x.shape[0])))
    _, _, vt = np.linalg.svd(a, full_matrices=False)
    p = vt[-1]
    m = np.array([[p[0], p[3], p[4]], [p[3], p[1], p[5]], [p[4], p[5], p[2]]])
    if np.trace(m) < 0:
        m, p = -m, -p
    try:
        centre = -np.linalg.solve(m, p[6:9])
    except np.linalg.LinAlgError:
        return None
    k = centre @ m @ centre - p[9]
    if not k > 0:
        return None
    m = m / k
    ev, evec = np.linalg.eigh(m)
    if not np.all(ev > 0):
        return None
    w0 = total * (evec * np.sqrt(ev)) @ evec.T
    return w0, centre + c0


G_M_S2 = 9.80665
PRIOR_SIGMA_SPEED_M_S = 20.0     # weak prior on the fitted forward speed (centripetal compensation)


def centripetal_direction(gyro_rad_s: np.ndarray) -> np.ndarray:
    """k = ω × x̂ / 1 m/s = [0, ω_z, −ω_y]: the body specific force added per m/s of forward speed in a turn
    (a = ω × v with v = [V, 0, 0] in the body frame, no sideslip)."""
    w = np.asarray(gyro_rad_s, dtype=np.float64)
    return np.column_stack((np.zeros(w.shape[0]), w[:, 2], -w[:, 1]))


def corrected_down(d0: np.ndarray, k: np.ndarray | None, speed_m_s) -> np.ndarray:
    """Down direction after removing the centripetal specific force V·k from the levelling: the measured
    specific force is −g·d0 (accelerometer, or an estimator whose roll/pitch follow it), so the true down is
    ∝ g·d0 + V·k."""
    if k is None:
        return d0
    u = d0 + np.asarray(speed_m_s, dtype=np.float64).reshape(-1, 1) * k / G_M_S2
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def fit_vertical_channel(raw: np.ndarray, roll_rad, pitch_rad, total_ut: float, vertical_ut: float | None, *,
                         sigma_mag_ut: float = ADIS16405_MAG_NOISE_UT,
                         sigma_tilt_rad: float = math.radians(DEFAULT_TILT_SIGMA_DEG),
                         prior_sigma: float = PRIOR_SIGMA_SOFT_IRON, init=None,
                         robust: bool = False, gyro_rad_s: np.ndarray | None = None,
                         speed_m_s=None) -> VerticalChannelFit:
    """Least-squares W (3×3) and h (3) with, per sample, c = W·(m − h):

        (|c| − F)/σ_F               magnitude equals the WMM total intensity F
        (c·d − H_z)/σ_V             levelled vertical component equals the WMM vertical intensity
                                    (d = NED down in the body frame from roll/pitch)

    plus a weak prior (σ = prior_sigma per W entry) towards the start value, which only matters for directions
    the data do not determine. `vertical_ut=None` fits the dip (H_z = F·sin δ) as a free parameter; F then only
    sets the scale. σ_V = √(σ_F² + (H_h·σ_tilt)²) accounts for the roll/pitch error.

    Turning vehicles: roll/pitch from the accelerometer (and from estimators that follow it) lean into the turn
    by atan(V·ω_z/g). With `gyro_rad_s`, `speed_m_s` removes it: a number or per-sample array (e.g. GNSS
    speed), or "fit" to estimate a constant forward speed as one more parameter (needs turns at varying rates
    or in both directions: a constant lean is indistinguishable from a sensor roll misalignment)."""
    from scipy.optimize import least_squares

    m = np.asarray(raw, dtype=np.float64)
    d0 = down_in_body(roll_rad, pitch_rad)
    n = m.shape[0]
    k = centripetal_direction(gyro_rad_s) if (gyro_rad_s is not None and speed_m_s is not None) else None
    fit_speed = k is not None and isinstance(speed_m_s, str)
    if isinstance(speed_m_s, str) and speed_m_s != "fit":
        raise ValueError(f"speed_m_s must be a number, an array or 'fit', not {speed_m_s!r}")
    d_fixed = corrected_down(d0, k, speed_m_s) if (k is not None and not fit_speed) else d0
    free_dip = vertical_ut is None
    total = float(total_ut)
    hz_guesses = [float(vertical_ut)] if not free_dip else [total * math.sin(math.radians(a))
                                                         for a in (-70, -50, -30, -10, 10, 30, 50, 70)]
    hh_ref = math.sqrt(max(total**2 - hz_guesses[0] ** 2, 0.0)) if not free_dip else 0.6 * total
    sig_f = float(sigma_mag_ut)
    sig_v = math.sqrt(sig_f**2 + (hh_ref * sigma_tilt_rad) ** 2)
    i_dip = 12 if free_dip else None
    i_speed = (12 + (1 if free_dip else 0)) if fit_speed else None
    npar = 12 + (1 if free_dip else 0) + (1 if fit_speed else 0)

    def unpack(p):
        hz = p[i_dip] * total if free_dip else float(vertical_ut)
        d = corrected_down(d0, k, p[i_speed]) if fit_speed else d_fixed
        return p[:9].reshape(3, 3), p[9:12], hz, d

    def make_fun(p0):
        prior_w = np.zeros(npar)
        prior_w[:9] = 1.0 / prior_sigma
        if free_dip:
            prior_w[i_dip] = 1.0 / 2.0          # sin δ in [−1, 1]: essentially free
        if fit_speed:
            prior_w[i_speed] = 1.0 / PRIOR_SIGMA_SPEED_M_S

        def fun(p):
            w, h, hz, d = unpack(p)
            c = (m - h) @ w.T
            nc = np.linalg.norm(c, axis=1)
            return np.concatenate(((nc - total) / sig_f, (np.einsum("ij,ij->i", c, d) - hz) / sig_v,
                                   (p - p0) * prior_w))

        def jac(p):
            w, h, _, d = unpack(p)
            e = m - h
            c = e @ w.T
            nc = np.linalg.norm(c, axis=1)
            u = c / nc[:, None]
            j = np.zeros((2 * n + npar, npar))
            j[:n, :9] = (u[:, :, None] * e[:, None, :]).reshape(n, 9) / sig_f
            j[:n, 9:12] = -(u @ w) / sig_f
            j[n:2 * n, :9] = (d[:, :, None] * e[:, None, :]).reshape(n, 9) / sig_v
            j[n:2 * n, 9:12] = -(d @ w) / sig_v
            if free_dip:
                j[n:2 * n, i_dip] = -total / sig_v
            if fit_speed:
                un = d0 + p[i_speed] * k / G_M_S2
                norm = np.linalg.norm(un, axis=1, keepdims=True)
                dd = (k / G_M_S2 - d * np.einsum("ij,ij->i", d, k / G_M_S2)[:, None]) / norm
                j[n:2 * n, i_speed] = np.einsum("ij,ij->i", c, dd) / sig_v
            j[2 * n:, :] = np.diag(prior_w)
            return j

        return fun, jac

    starts = []
    if init is not None:
        starts.append(("given", np.asarray(init[0], dtype=np.float64), np.asarray(init[1], dtype=np.float64)))
    ell = _ellipsoid_init(m, total)
    for hz0 in hz_guesses:
        lev = _conic_init(m, d_fixed, total, hz0)
        if lev is not None:
            starts.append((f"level (dip {math.degrees(math.asin(max(-1, min(1, hz0 / total)))):.0f}°)", *lev, hz0))
    if ell is not None:
        for hz0 in (hz_guesses if free_dip else hz_guesses[:1]):
            starts.append(("ellipsoid", *ell, hz0))
    if not starts:
        raise BacksteppingError("no start value: the horizontal components do not trace an ellipse "
                                "(turn the vehicle through a full circle)")

    def solve(p0, max_nfev):
        fun, jac = make_fun(p0)
        try:
            if robust:
                sol = least_squares(fun, p0, jac=jac, method="trf", x_scale="jac", max_nfev=max_nfev,
                                    loss="soft_l1", f_scale=3.0)
            else:   # MINPACK LM (QR): much cheaper per iteration than TRF's SVD
                sol = least_squares(fun, p0, jac=jac, method="lm", x_scale="jac", max_nfev=max_nfev)
        except (ValueError, np.linalg.LinAlgError):
            return None
        cost = float(np.sum(sol.fun[:2 * n] ** 2))
        return (cost, sol, jac) if np.isfinite(cost) else None

    # stage 1: a few iterations from every start; stage 2: the best one to convergence
    best = None
    for start in starts:
        name, w0, h0 = start[0], start[1], start[2]
        hz0 = start[3] if len(start) > 3 else hz_guesses[0]
        p0 = np.concatenate((w0.ravel(), h0, [hz0 / total] if free_dip else [], [0.0] if fit_speed else []))
        got = solve(p0, 8 if len(starts) > 1 else 200)
        if got is not None and (best is None or got[0] < best[0]):
            best = (got[0], got[1], name, p0)
    if best is None:
        raise BacksteppingError("the vertical-channel least squares did not converge from any start value")
    _, sol1, name, p0 = best
    # the prior is re-centred on the stage-1 result; it is weak, so this only matters for directions the data
    # do not determine at all
    got = solve(sol1.x, 200) if len(starts) > 1 else (best[0], sol1, make_fun(p0)[1])
    if got is None:
        raise BacksteppingError("the vertical-channel least squares did not converge")
    cost, sol, jac = got
    w, h, hz, _ = unpack(sol.x)
    r = sol.fun[:2 * n]
    jd = jac(sol.x)[:2 * n]
    names = list(_PARAM_NAMES) + (["sin_dip"] if free_dip else []) + (["speed_m_s"] if fit_speed else [])
    speed = float(sol.x[i_speed]) if fit_speed else None
    return VerticalChannelFit(w, h, total, hz, free_dip, float(np.sqrt(np.mean((r[:n] * sig_f) ** 2))),
                              float(np.sqrt(np.mean((r[n:] * sig_v) ** 2))), float(np.sqrt(np.mean(r**2))),
                              jd, names, name, int(sol.nfev), bool(sol.success), str(sol.message), speed)


def predicted_heading_std_deg(fit: VerticalChannelFit, tilt_envelope_deg: float, *,
                              prior_sigma: float = PRIOR_SIGMA_SOFT_IRON, n_headings: int = 12) -> dict:
    """Propagate the fit's parameter covariance (data + the weak prior) to the tilt-compensated heading on a
    grid of attitudes (every 360/n_headings° of heading; level and ±tilt_envelope in roll and in pitch). Returns
    the 1σ of the constant heading offset (what a heading reference would remove) and the RMS 1σ of the
    heading-dependent part."""
    j = fit.jacobian
    npar = j.shape[1]
    info = j.T @ j * (1.0 / max(fit.whitened_rms, 1.0) ** 2)
    prior = np.zeros(npar)
    prior[:9] = 1.0 / prior_sigma**2
    for i, name in enumerate(fit.names):
        if name == "sin_dip":
            prior[i] = 0.25
        elif name == "speed_m_s":
            prior[i] = 1.0 / PRIOR_SIGMA_SPEED_M_S**2
    cov = np.linalg.pinv(info + np.diag(prior))
    hh = math.sqrt(max(fit.total_ut**2 - fit.vertical_ut**2, 0.0))
    t = math.radians(tilt_envelope_deg)
    atts = [(r, p) for r, p in ((0, 0), (t, 0), (-t, 0), (0, t), (0, -t))]
    psi = np.radians(np.arange(n_headings) * 360.0 / n_headings)
    roll = np.repeat([a[0] for a in atts], psi.size)
    pitch = np.repeat([a[1] for a in atts], psi.size)
    yaw = np.tile(psi, len(atts))
    from ahrsd.estimator.rotations import euler_to_dcm

    cbn = euler_to_dcm(roll, pitch, yaw)
    b = np.einsum("nji,j->ni", cbn, np.array([hh, 0.0, fit.vertical_ut]))   # C_n^b · H^n
    winv = np.linalg.inv(fit.soft_iron)
    raw = b @ winv.T + fit.hard_iron_ut
    p0 = np.concatenate((fit.soft_iron.ravel(), fit.hard_iron_ut, [fit.vertical_ut / fit.total_ut] if fit.free_dip else [],
                         [fit.speed_m_s] if fit.speed_m_s is not None else []))

    def heading(p):
        w, h = p[:9].reshape(3, 3), p[9:12]
        return np.radians(magnetic_heading_deg((raw - h) @ w.T, roll, pitch))

    base = heading(p0)
    grad = np.zeros((base.size, npar))
    for k in range(npar):
        step = 1e-6 * max(1.0, abs(p0[k]))
        dp = np.zeros(npar)
        dp[k] = step
        grad[:, k] = _wrap_pi_arr(heading(p0 + dp) - base) / step
    gm = grad.mean(axis=0)
    gv = grad - gm
    offset = math.degrees(math.sqrt(max(gm @ cov @ gm, 0.0)))
    varying = math.degrees(math.sqrt(max(np.mean(np.einsum("ij,jk,ik->i", gv, cov, gv)), 0.0)))
    return {"offset_std_deg": offset, "heading_dependent_std_deg": varying, "envelope_tilt_deg": tilt_envelope_deg}


def _wrap_pi_arr(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


# ================================================================================ attitude and decimation


def roll_pitch_from_estimator(data: MagFitInput, name: str = "mekf") -> tuple[np.ndarray, np.ndarray]:
    """Run `ahrsd.estimator.make_estimator(name)` over the samples (raw magnetometer: the estimator's design
    keeps magnetometer errors out of roll/pitch) and return its roll and pitch per sample."""
    from ahrsd.core.sample import make_sample
    from ahrsd.estimator import make_estimator

    if data.gyro_rad_s is None or data.accel_m_s2 is None:
        raise BacksteppingError("the estimator needs gyro and accelerometer samples")
    est = make_estimator(name)
    n = len(data)
    roll, pitch = np.empty(n), np.empty(n)
    for i in range(n):
        e = est.update(make_sample(data.t_s[i], data.gyro_rad_s[i], data.accel_m_s2[i], data.mag_ut[i]))
        roll[i], pitch[i] = e.roll_rad, e.pitch_rad
    return roll, pitch


def block_average(t_s: np.ndarray, rate_hz: float, *columns):
    """Average consecutive samples in blocks of 1/rate_hz seconds. Returns (t_block, [averaged columns]) and
    the block index of every input sample. Columns may be None."""
    t = np.asarray(t_s, dtype=np.float64)
    if t.size == 0:
        return t, [c for c in columns], np.zeros(0, dtype=int)
    if rate_hz is None or rate_hz <= 0:
        return t, list(columns), np.arange(t.size)
    idx = np.floor((t - t[0]) * rate_hz).astype(np.int64)
    _, inv, counts = np.unique(idx, return_inverse=True, return_counts=True)
    nb = counts.size

    def avg(x):
        if x is None:
            return None
        x = np.asarray(x, dtype=np.float64)
        out = np.zeros((nb,) + x.shape[1:])
        np.add.at(out, inv, x)
        return out / counts.reshape((-1,) + (1,) * (x.ndim - 1))

    return avg(t), [avg(c) for c in columns], inv


# ============================================================================================ entry point


def fit_backstepping(data: MagFitInput, reference=None, *, model: str = "general", attitude: str = "auto",
                     roll_rad=None, pitch_rad=None, rate_hz: float = DEFAULT_FIT_RATE_HZ,
                     accel_tau_s: float = 0.2, field_ut: float | None = None,
                     inclination_deg: float | None = None, free_dip: bool | None = None, legs=None,
                     calibration_mask=None, heading_ref_delay_s: float = 0.0, fold_offset: bool = True,
                     sigma_mag_ut: float = ADIS16405_MAG_NOISE_UT, sigma_tilt_deg: float = DEFAULT_TILT_SIGMA_DEG,
                     step_tol_ut: float = PAPER_STEP_TOL_UT, max_passes: int = 10,
                     max_heading_std_deg: float = MAX_PREDICTED_HEADING_STD_DEG, robust="auto",
                     estimator: str = "mekf", speed_m_s="auto") -> MagFitResult:
    """Back-stepping / vertical-channel magnetometer calibration (the `fit_mag` "backstepping" method).

    reference: WMM `EarthField` at the site (total, vertical intensity, declination). Without it (and without
    field_ut/inclination_deg) the dip is fitted freely and the scale is the mean raw magnitude.

    Options:
      model            "general" (full soft iron, vertical-channel least squares; default) or "paper"
                       (seed 002 as printed: axis-aligned sphere fit + corrective loop on the legs).
      attitude         "auto"/"accel" (low-passed accelerometer roll/pitch, centripetal lean fitted out on a
                       turning vehicle), or "mekf"/"estimator" (run the estimator over the samples).
                       roll_rad/pitch_rad arrays override both.
      rate_hz          block-average to this rate before fitting (None: use every sample).
      legs             int label per sample for the out-and-back / multi-leg run (−1: not on a leg); default:
                       detected from the calibrated heading (straight runs ≥ 60 s).
      calibration_mask ("paper") samples for the sphere fit (test 1); the rest is the leg run (test 2).
      heading_ref_delay_s  latency of data.heading_ref_deg (GNSS course: seed 002 used 2 s).
      fold_offset      fold the fitted constant heading offset A into the soft iron (a yaw rotation).
      robust           "auto" (refit with a soft-L1 loss when > 1 % of samples are magnetically disturbed),
                       True or False.
      speed_m_s        centripetal compensation of the levelling in turns (needs gyro samples): "auto"
                       ("fit" when gyro samples exist, else none), "fit" (a constant forward speed is fitted),
                       a number or a per-sample array (GNSS speed), or None (no compensation).
    """
    t0 = time.perf_counter()
    if model not in ("general", "paper"):
        raise ValueError(f"unknown backstepping model {model!r}; choose 'general' or 'paper'")
    keep = finite_rows(data.mag_ut)
    if data.accel_m_s2 is not None:
        keep &= np.all(np.isfinite(data.accel_m_s2), axis=1)
    dropped = int((~keep).sum())
    full = data.select(keep) if dropped else data
    rp_given = roll_rad is not None and pitch_rad is not None
    if rp_given:
        roll_rad = np.asarray(roll_rad, dtype=np.float64)[keep]
        pitch_rad = np.asarray(pitch_rad, dtype=np.float64)[keep]
    legs_in = None if legs is None else np.asarray(legs)[keep]
    cal_mask_in = None if calibration_mask is None else np.asarray(calibration_mask, dtype=bool)[keep]
    quality: dict = {"n_input": len(data), "n_dropped_nonfinite": dropped, "model": model}
    if len(full) < 10:
        return refuse(METHOD, f"only {len(full)} usable samples", **quality)

    # --- roll and pitch
    # "auto": the low-passed accelerometer, with the centripetal lean fitted out on a vehicle (tilt within ±30°).
    # Measured (bench/magcal.py, simulator): boat in turns 0.68° heading RMS vs 1.94° with the MEKF's roll/pitch
    # (which lean ~1.4° into the turn like the accelerometer, and cannot be compensated afterwards); hand tumble
    # 0.50° vs 1.04°. The estimator stays available as attitude="mekf".
    source = "given"
    vehicle_like = True
    if not rp_given and full.accel_m_s2 is not None:
        r0, p0 = roll_pitch_from_accel(full.accel_m_s2)
        vehicle_like = float(np.percentile(np.degrees(np.arccos(np.clip(np.cos(r0) * np.cos(p0), -1, 1))), 99)) <= 30.0
    if attitude not in ("auto", "accel", "mekf", "estimator"):
        raise ValueError(f"unknown attitude source {attitude!r}")
    if not rp_given:
        if full.accel_m_s2 is None:
            return refuse(METHOD, "back-stepping needs roll and pitch: the recording has no accelerometer "
                          "samples (or pass roll_rad/pitch_rad)", **quality)
        use_estimator = attitude in ("mekf", "estimator")
        if use_estimator and full.gyro_rad_s is not None:
            try:
                roll_rad, pitch_rad = roll_pitch_from_estimator(full, estimator)
                source = f"estimator:{estimator}"
            except (ImportError, NotImplementedError, AttributeError, BacksteppingError) as exc:
                if attitude != "auto":
                    return refuse(METHOD, f"the estimator could not provide roll/pitch: {exc}", **quality)
                roll_rad = None
                quality["attitude_fallback"] = f"estimator unavailable ({type(exc).__name__}: {exc}); accelerometer used"
        elif use_estimator and attitude != "auto":
            return refuse(METHOD, "the estimator needs gyro samples for roll/pitch", **quality)
        if roll_rad is None:
            acc = lowpass(full.accel_m_s2, full.t_s, accel_tau_s)
            roll_rad, pitch_rad = roll_pitch_from_accel(acc)
            source = f"accelerometer (low-pass τ={accel_tau_s:g} s)"
    quality["attitude_source"] = source

    # --- decimate (average in blocks); roll/pitch through their sines/cosines-free small-angle mean is fine
    href = full.heading_ref_deg
    href_c = href_s = None
    if href is not None:
        shifted = href
        if heading_ref_delay_s:
            ok = np.isfinite(href)
            shifted = np.full_like(href, np.nan)
            if ok.sum() >= 2:
                unwrapped = np.degrees(np.unwrap(np.radians(href[ok])))
                tq = full.t_s + heading_ref_delay_s
                inside = (tq >= full.t_s[ok][0]) & (tq <= full.t_s[ok][-1])
                # only between two valid reference samples: never bridge a gap in the reference
                idx = np.clip(np.searchsorted(full.t_s, tq), 1, len(full) - 1)
                inside &= ok[idx] & ok[idx - 1]
                shifted[inside] = np.interp(tq[inside], full.t_s[ok], unwrapped) % 360.0
        href_c, href_s = np.cos(np.radians(shifted)), np.sin(np.radians(shifted))
    leg_f = None if legs_in is None else legs_in.astype(np.float64)
    cal_f = None if cal_mask_in is None else cal_mask_in.astype(np.float64)
    speed_in = speed_m_s
    if isinstance(speed_in, str) and speed_in == "auto":
        # the forward-speed model a = ω × [V, 0, 0] describes a vehicle, not a hand tumble
        speed_in = "fit" if (full.gyro_rad_s is not None and vehicle_like) else None
    speed_arr = None
    if speed_in is not None and not isinstance(speed_in, str):
        speed_arr = np.broadcast_to(np.asarray(speed_in, dtype=np.float64), (len(data),))[keep].astype(np.float64)
    # roll/pitch are averaged as the down vector (angles wrap at ±180° in a tumble)
    tb, cols, block_of = block_average(full.t_s, rate_hz, full.mag_ut, down_in_body(roll_rad, pitch_rad),
                                       leg_f, cal_f, full.gyro_rad_s if speed_in is not None else None, speed_arr)
    mag, down_b, legf, calf, gyro_b, speed_b = cols
    # the heading reference is averaged over its valid samples only: a sparse reference (GNSS fixes at 1–10 Hz
    # in a fast recording, NaN between them) must not be lost because a block also holds NaN rows
    hc = hs = None
    if href_c is not None:
        nb = mag.shape[0]
        valid = np.isfinite(href_c)
        count = np.bincount(block_of, weights=valid.astype(np.float64), minlength=nb)
        with np.errstate(invalid="ignore", divide="ignore"):
            hc = np.bincount(block_of, weights=np.where(valid, href_c, 0.0), minlength=nb) / count
            hs = np.bincount(block_of, weights=np.where(valid, href_s, 0.0), minlength=nb) / count
    down_b = down_b / np.linalg.norm(down_b, axis=1, keepdims=True)
    roll = np.arctan2(down_b[:, 1], down_b[:, 2])
    pitch = -np.arcsin(np.clip(down_b[:, 0], -1.0, 1.0))
    if speed_in is not None and gyro_b is None:
        return refuse(METHOD, "centripetal compensation (speed_m_s) needs gyro samples; pass speed_m_s=None", **quality)
    centripetal = None if speed_in is None else (gyro_b, speed_b if speed_b is not None else speed_in)
    legs_b = None if legf is None else np.where(np.abs(legf - np.round(legf)) < 1e-9, np.round(legf), -1).astype(int)
    cal_b = None if calf is None else calf > 0.5
    heading_ref_b = None
    if hc is not None:
        heading_ref_b = np.degrees(np.arctan2(hs, hc)) % 360.0
        with np.errstate(invalid="ignore"):
            heading_ref_b[~(np.hypot(hc, hs) > 0.99)] = np.nan    # no reference in the block, or it straddled a turn
    quality["n_used"] = int(mag.shape[0])
    quality["fit_rate_hz"] = rate_hz
    # averaging k samples divides the white magnetometer noise by √k
    per_block = len(full) / max(mag.shape[0], 1)
    sigma_mag_ut = sigma_mag_ut / math.sqrt(max(per_block, 1.0))
    quality["sigma_mag_fit_ut"] = sigma_mag_ut

    # --- reference field
    if field_ut is not None:
        total = float(field_ut)
        total_src = "given"
    elif reference is not None:
        total = float(reference.total_ut)
        total_src = "wmm"
    else:
        total = float(np.mean(np.linalg.norm(mag - mag.mean(axis=0), axis=1)))
        total_src = "none: scale from the data (heading unaffected)"
    if inclination_deg is not None:
        vertical = total * math.sin(math.radians(inclination_deg))
    elif reference is not None:
        vertical = total * math.sin(reference.inclination_rad)
    else:
        vertical = None
    if free_dip:
        vertical = None
    declination_deg = math.degrees(reference.declination_rad) if reference is not None else 0.0
    quality["reference"] = {"total_ut": total, "total_source": total_src,
                            "vertical_ut": vertical, "declination_deg": declination_deg}

    # --- what the data support
    support_model = "diagonal" if model == "paper" else ("vertical" if vertical is not None else "vertical-free-dip")
    support = assess_support(mag, None, support_model, roll_rad=roll, pitch_rad=pitch,
                             reference_known=vertical is not None,
                             horizontal_ut=math.sqrt(max(total**2 - vertical**2, 0.0)) if vertical is not None else None)
    quality.update(support.as_quality())
    if support.refused:
        return refuse(METHOD, support.refused, **quality)

    levelling: dict = {}
    if model == "paper":
        result = _fit_paper(tb, mag, roll, pitch, total, vertical, legs_b, cal_b, quality, step_tol_ut, max_passes)
    else:
        result = _fit_general(tb, mag, roll, pitch, total, vertical, legs_b, quality, sigma_mag_ut, sigma_tilt_deg,
                              max_heading_std_deg, robust, support, centripetal, levelling)
    if isinstance(result, MagFitResult):
        return result
    mag_model = result

    # --- heading reference: deviation coefficients, constant offset folded into the soft iron
    if heading_ref_b is not None and np.isfinite(heading_ref_b).sum() >= 1:
        # heading from the same levelling the fit used: with the accelerometer's lean into turns left in, a boat
        # turning one way shows a spurious semicircular term (measured: C ≈ 2.7° on the simulated boat)
        roll_h, pitch_h = roll, pitch
        speed_used = levelling.get("speed_m_s")
        if speed_used is not None and not isinstance(speed_used, str) and gyro_b is not None:
            d = corrected_down(down_b, centripetal_direction(gyro_b), speed_used)
            roll_h, pitch_h = np.arctan2(d[:, 1], d[:, 2]), -np.arcsin(np.clip(d[:, 0], -1.0, 1.0))
        mag_model = _apply_heading_reference(mag_model, mag, roll_h, pitch_h, heading_ref_b, declination_deg,
                                             fold_offset, quality)

    res = np.linalg.norm(mag_model.apply(mag), axis=1) - total
    # keys shared with the other magnetometer fits (`ahrsd calibrate mag` prints them)
    quality["coverage"] = quality.get("sphere_coverage")
    quality["residual_max_ut"] = float(np.max(np.abs(res)))
    std = quality.get("parameter_std", {})
    if std:
        quality["sigma_hard_iron_ut"] = [std.get(f"hard_iron_{a}_ut", math.nan) for a in "xyz"]
    quality["time_s"] = time.perf_counter() - t0
    return MagFitResult(mag_model, float(np.sqrt(np.mean(res**2))), METHOD, quality, None)


def _fit_general(t_s, mag, roll, pitch, total, vertical, legs_b, quality, sigma_mag_ut, sigma_tilt_deg,
                 max_heading_std_deg, robust, support, centripetal=None, levelling=None):
    # the paper's sphere fit, for comparison (it often fails or is wrong on level data: that is the point)
    sph = sphere_fit_paper(mag, total)
    quality["sphere_fit_paper"] = ({"b_ut": sph.model.bias.tolist(), "s": sph.model.scale.tolist(),
                                    "condition_number": sph.condition_number} if sph.model is not None
                                   else {"refused": sph.reason, "condition_number": sph.condition_number})
    cen = centripetal   # None once the fit runs without centripetal compensation
    try:
        fit = fit_vertical_channel(mag, roll, pitch, total, vertical, sigma_mag_ut=sigma_mag_ut,
                                   sigma_tilt_rad=math.radians(sigma_tilt_deg), robust=robust is True,
                                   gyro_rad_s=None if centripetal is None else centripetal[0],
                                   speed_m_s=None if centripetal is None else centripetal[1])
        if fit.speed_m_s is not None:
            lean = np.max(np.abs(fit.speed_m_s * centripetal[0][:, 2])) / G_M_S2
            if not (abs(fit.speed_m_s) <= MAX_FITTED_SPEED_M_S and lean <= MAX_CENTRIPETAL_LEAN_RAD):
                quality.setdefault("warnings", []).append(
                    f"the fitted centripetal speed {fit.speed_m_s:.1f} m/s (lean up to {math.degrees(lean):.1f}°) is "
                    "not plausible: refitted without centripetal compensation")
                cen = None
                fit = fit_vertical_channel(mag, roll, pitch, total, vertical, sigma_mag_ut=sigma_mag_ut,
                                           sigma_tilt_rad=math.radians(sigma_tilt_deg), robust=robust is True)
        # magnetic disturbances (a passing vehicle, a steel pier) show as magnitude outliers: count them and,
        # when more than 1 % of the samples are disturbed, refit with a robust (soft-L1) loss
        mres = np.linalg.norm((mag - fit.hard_iron_ut) @ fit.soft_iron.T, axis=1) - total
        scale = max(1.4826 * float(np.median(np.abs(mres - np.median(mres)))), sigma_mag_ut)
        disturbed = int(np.sum(np.abs(mres) > DISTURBANCE_SIGMAS * scale))
        quality["disturbed_samples"] = disturbed
        if robust == "auto" and disturbed > DISTURBED_FRACTION_FOR_ROBUST * mag.shape[0]:
            fit = fit_vertical_channel(mag, roll, pitch, total, vertical, sigma_mag_ut=sigma_mag_ut,
                                       sigma_tilt_rad=math.radians(sigma_tilt_deg), robust=True,
                                       gyro_rad_s=None if cen is None else cen[0],
                                       speed_m_s=None if cen is None else cen[1])
            quality.setdefault("warnings", []).append(
                f"{disturbed} of {mag.shape[0]} samples look magnetically disturbed (|H| off by more than "
                f"{DISTURBANCE_SIGMAS:g}σ): refitted with a robust loss")
    except BacksteppingError as exc:
        return refuse(METHOD, str(exc), **quality)
    w, h = fit.soft_iron, fit.hard_iron_ut
    if levelling is not None:   # the forward speed the levelling was compensated with (None: not compensated)
        levelling["speed_m_s"] = (fit.speed_m_s if fit.speed_m_s is not None else
                                  (cen[1] if cen is not None else None))
    quality["vertical_channel"] = {
        "init": fit.init, "nfev": fit.nfev, "converged": fit.success, "message": fit.message,
        "magnitude_rms_ut": fit.magnitude_rms_ut, "vertical_rms_ut": fit.vertical_rms_ut,
        "whitened_rms": fit.whitened_rms, "vertical_ut": fit.vertical_ut, "free_dip": fit.free_dip,
        "centripetal_speed_m_s": (fit.speed_m_s if fit.speed_m_s is not None else
                                  ("given" if cen is not None else None)),
    }
    if fit.free_dip:
        quality["vertical_channel"]["dip_deg"] = math.degrees(math.asin(max(-1.0, min(1.0, fit.vertical_ut / total))))
    limits = {n: 0.02 for n in fit.names[:9]}
    limits.update({n: 1.0 for n in fit.names[9:12]})
    unc = parameter_uncertainty(fit.jacobian, fit.names, limits, residual_scale=max(fit.whitened_rms, 1.0))
    quality["condition_number"] = unc["condition_number"]
    quality["parameter_std"] = unc["std"]
    quality["undetermined"] = unc["undetermined"]
    envelope = max(10.0, support.tilt["tilt_max_deg"]) if support.tilt else 10.0
    pred = predicted_heading_std_deg(fit, envelope)
    quality["predicted_heading"] = pred
    if np.linalg.det(w) <= 0:
        return refuse(METHOD, "the fitted soft iron is a reflection (det ≤ 0): heading would be mirrored", **quality)
    if not fit.success and fit.whitened_rms > 10:
        return refuse(METHOD, f"the fit did not converge ({fit.message})", **quality)
    if pred["heading_dependent_std_deg"] > max_heading_std_deg:
        return refuse(METHOD, f"the data leave the heading uncertain by {pred['heading_dependent_std_deg']:.1f}° "
                      f"(1σ, within ±{envelope:.0f}° tilt; limit {max_heading_std_deg:.1f}°); parameters the data "
                      f"cannot determine: {', '.join(unc['undetermined']) or 'combinations of several'}", **quality)
    if pred["offset_std_deg"] > 0.5:
        quality.setdefault("warnings", []).append(
            f"the constant heading offset (yaw misalignment, coefficient A) is determined only to "
            f"{pred['offset_std_deg']:.1f}° (1σ); give a heading reference (GNSS course or known headings)")
    model = MagModel(h, w)
    _leg_report(t_s, model, mag, roll, pitch, legs_b, quality, sph.model.to_mag_model() if sph.model else None)
    return model


def _leg_report(t_s, model: MagModel, mag, roll, pitch, legs_b, quality, before: MagModel | None):
    cal = model.apply(mag)
    legs = legs_b
    if legs is None:
        legs = segment_legs(t_s, magnetic_heading_deg(cal, roll, pitch))
        quality_key = "legs_detected"
    else:
        quality_key = "legs_given"
    stats = leg_statistics(cal, roll, pitch, legs)
    if len(stats) < 2:
        return
    rep = {"source": quality_key, "legs": [s.__dict__ for s in stats], "step_after_ut": inter_leg_step_ut(stats)}
    if before is not None:
        rep["step_sphere_fit_ut"] = inter_leg_step_ut(leg_statistics(before.apply(mag), roll, pitch, legs))
    quality["out_and_back"] = rep


def _fit_paper(t_s, mag, roll, pitch, total, vertical, legs_b, cal_b, quality, step_tol_ut, max_passes):
    if vertical is None:
        return refuse(METHOD, "the paper's corrective steps need the reference horizontal and vertical "
                      "intensity (give the position for WMM)", **quality)
    sel = cal_b if cal_b is not None and cal_b.any() else np.ones(mag.shape[0], dtype=bool)
    sph = sphere_fit_paper(mag[sel], total)
    quality["sphere_fit_paper"] = {"condition_number": sph.condition_number, "n": int(sel.sum())}
    if sph.model is None:
        return refuse(METHOD, f"sphere fit (seed 002 eq. 12–17): {sph.reason}", **quality)
    quality["sphere_fit_paper"].update(b_ut=sph.model.bias.tolist(), s=sph.model.scale.tolist())
    hh_ref = math.sqrt(total**2 - vertical**2)
    legs = legs_b
    if legs is None or (legs >= 0).sum() == 0:
        rest = ~sel if (~sel).any() else sel
        cal = sph.model.apply(mag)
        legs = np.where(rest, segment_legs(t_s, magnetic_heading_deg(cal, roll, pitch)), -1)
        if (legs >= 0).sum() == 0:
            legs = np.where(rest, 0, -1)
    try:
        bs = backstep_correct(mag, roll, pitch, legs, sph.model, hh_ref, vertical, step_tol_ut=step_tol_ut,
                              field_tol_ut=step_tol_ut, max_passes=max_passes)
    except BacksteppingError as exc:
        return refuse(METHOD, str(exc), **quality)
    sz_ratio = bs.model.scale[2] / sph.model.scale[2]
    if not 0.5 < sz_ratio < 2.0:
        quality.setdefault("warnings", []).append(
            f"the loop changed s_z by a factor {sz_ratio:.2f}: the step is being absorbed by a non-physical "
            "vertical scale, typically horizontal→vertical coupling (off-diagonal soft iron) that the paper's "
            "diagonal model cannot represent; use the general model")
    quality["backstep"] = {"passes": [p.to_dict() for p in bs.passes], "converged": bs.converged,
                           "stop_reason": bs.stop_reason, "step_before_ut": bs.step_before_ut,
                           "step_after_ut": bs.step_after_ut, "n_legs": int(np.unique(legs[legs >= 0]).size)}
    return bs.model.to_mag_model()


def _apply_heading_reference(model: MagModel, mag, roll, pitch, heading_ref_true_deg, declination_deg,
                             fold_offset, quality) -> MagModel:
    ok = np.isfinite(heading_ref_true_deg)
    psi = magnetic_heading_deg(model.apply(mag[ok]), roll[ok], pitch[ok])
    ref_mag = (heading_ref_true_deg[ok] - declination_deg) % 360.0
    rep: dict = {"n": int(ok.sum())}
    try:
        dev = swing.fit_deviation(psi, ref_mag)
    except swing.SwingFitError as exc:
        dev = swing.fit_offset(psi, ref_mag)
        rep["note"] = f"A only: {exc}"
    rep.update(dev.to_dict())
    # seed 002 §5 sanity rule: A from the full fit should agree with A alone
    if math.isfinite(dev.a_only_deg) and abs(dev.a_deg - dev.a_only_deg) > 1.0:
        rep["warning"] = (f"A of the full fit ({dev.a_deg:.2f}°) differs from A alone ({dev.a_only_deg:.2f}°): "
                          "the reference headings are too few or unevenly spread (seed 002 §5)")
    offset = dev.a_only_deg if "note" not in rep else dev.a_deg
    if fold_offset:
        model = fold_heading_offset(model, offset)
        rep["folded_offset_deg"] = offset
        psi2 = magnetic_heading_deg(model.apply(mag[ok]), roll[ok], pitch[ok])
        rep["rms_after_fold_deg"] = float(np.sqrt(np.mean(swing.wrap180(ref_mag - psi2) ** 2)))
    quality["heading_reference"] = rep
    return model


# ================================================================================================== plot


def plot_backstepping(result: MagFitResult, data: MagFitInput, path, *, roll_rad=None, pitch_rad=None,
                      reference=None, swing_table=None) -> None:
    """Report figure: levelled horizontal field before/after (should be a circle of radius H_h), |H| and H_z
    over time before/after, and heading error vs heading when data.heading_ref_deg exists or a compass-swing
    table `swing_table=(reference_deg, compass_deg)` is given (its points and the fitted card). Writes `path`.
    Raises PlotUnavailableError when matplotlib (the `ahrsd[plot]` extra) is not installed."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise PlotUnavailableError(f"plotting needs matplotlib: {PLOT_INSTALL_HINT} ({exc})") from None

    ok = finite_rows(data.mag_ut)
    d = data.select(ok)
    if roll_rad is None:
        if d.accel_m_s2 is None:
            raise BacksteppingError("plot needs roll/pitch or accelerometer samples")
        roll_rad, pitch_rad = roll_pitch_from_accel(lowpass(d.accel_m_s2, d.t_s, 0.2))
        # level as the fit did: without the accelerometer's lean into turns (the fitted forward speed)
        speed = result.quality.get("vertical_channel", {}).get("centripetal_speed_m_s")
        if isinstance(speed, (int, float)) and d.gyro_rad_s is not None:
            dn = corrected_down(down_in_body(roll_rad, pitch_rad), centripetal_direction(d.gyro_rad_s), speed)
            roll_rad, pitch_rad = np.arctan2(dn[:, 1], dn[:, 2]), -np.arcsin(np.clip(dn[:, 0], -1.0, 1.0))
    else:
        roll_rad, pitch_rad = np.asarray(roll_rad)[ok], np.asarray(pitch_rad)[ok]
    raw = d.mag_ut - np.median(d.mag_ut, axis=0)
    cal = result.model.apply(d.mag_ut)
    lv_raw, lv_cal = level_vectors(raw, roll_rad, pitch_rad), level_vectors(cal, roll_rad, pitch_rad)
    has_ref = (d.heading_ref_deg is not None and np.isfinite(d.heading_ref_deg).any()) or swing_table is not None
    fig, axes = plt.subplots(1, 3 if has_ref else 2, figsize=(15 if has_ref else 10, 4.5))
    ax = axes[0]
    ax.plot(lv_raw[:, 1], lv_raw[:, 0], ".", ms=1, label="raw (centred)")
    ax.plot(lv_cal[:, 1], lv_cal[:, 0], ".", ms=1, label="calibrated")
    q = result.quality.get("reference", {})
    if q.get("vertical_ut") is not None:
        hh = math.sqrt(max(q["total_ut"] ** 2 - q["vertical_ut"] ** 2, 0))
        th = np.linspace(0, 2 * math.pi, 200)
        ax.plot(hh * np.sin(th), hh * np.cos(th), "k--", lw=0.8, label=f"WMM H_h {hh:.1f} µT")
    ax.set_aspect("equal")
    ax.set_xlabel("east-ish (µT)")
    ax.set_ylabel("north-ish (µT)")
    ax.set_title("levelled horizontal field")
    ax.legend(fontsize=7)
    ax = axes[1]
    ax.plot(d.t_s, np.linalg.norm(cal, axis=1), lw=0.6, label="|H| calibrated")
    ax.plot(d.t_s, lv_cal[:, 2], lw=0.6, label="H_z calibrated")
    if q.get("total_ut"):
        ax.axhline(q["total_ut"], color="k", ls="--", lw=0.8)
    if q.get("vertical_ut") is not None:
        ax.axhline(q["vertical_ut"], color="k", ls=":", lw=0.8)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("µT")
    ax.set_title(f"{result.method}: residual {result.residual_rms_ut:.3f} µT")
    ax.legend(fontsize=7)
    if has_ref:
        ax = axes[2]
        if d.heading_ref_deg is not None and np.isfinite(d.heading_ref_deg).any():
            psi = magnetic_heading_deg(cal, roll_rad, pitch_rad)
            decl = q.get("declination_deg", 0.0) or 0.0
            err = swing.wrap180((d.heading_ref_deg - decl) - psi)
            ax.plot(psi, err, ".", ms=2, label="recording (heading_ref_deg)")
        if swing_table is not None:
            ref_deg, compass_deg = (np.asarray(a, dtype=np.float64) for a in swing_table)
            ax.plot(compass_deg, swing.wrap180(ref_deg - compass_deg), "o", label="swing table")
            card = result.quality.get("heading_reference", {})
            if "B_deg" in card:
                grid = np.linspace(0.0, 360.0, 181)
                coef = swing.DeviationCoefficients(card["A_deg"], card["B_deg"], card["C_deg"], card["D_deg"],
                                                   card["E_deg"])
                ax.plot(grid, coef.deviation_deg(grid), "k-", lw=0.8, label="card A..E (before folding A)")
        ax.legend(fontsize=7)
        ax.set_xlabel("magnetic heading (deg)")
        ax.set_ylabel("reference − magnetometer (deg)")
        ax.set_title("heading error vs heading")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
