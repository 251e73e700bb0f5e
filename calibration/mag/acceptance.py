"""Acceptance checks shared by the magnitude-based magnetometer fits (ellipsoid, two-step, three-step):
the common first step (`prepare`), the reference magnitude, orientation coverage, parameter 1σ and the
refusal reasons (`assess`), with ArduPilot's COMPASS_CAL_FIT as the residual limit.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Callable

import numpy as np

from ..models import MagModel
from .fit_types import MagFitInput, MagFitResult, finite_rows, refuse

if TYPE_CHECKING:  # pragma: no cover
    from ahrsd.core.wmm import EarthField


def magnitude_residuals(model: MagModel, mag_ut: np.ndarray, field_ut: float) -> np.ndarray:
    """|model(raw)| − field_ut per sample (µT)."""
    return np.linalg.norm(model.apply(mag_ut), axis=1) - field_ut


def direction_coverage(unit_vectors: np.ndarray, n_bins: int = 26) -> float:
    """Fraction (0…1) of `n_bins` evenly spread directions that have a sample within ~38° of them
    (the 26 face/edge/corner directions of a cube). A full tumble gives 1.0, a level turn ≈ 0.3."""
    dirs = _cube_directions()
    u = np.asarray(unit_vectors, dtype=np.float64)
    if u.size == 0:
        return 0.0
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    cos_limit = math.cos(math.radians(38.0))
    # Dot products in chunks so hours of data do not build a huge matrix.
    hit = np.zeros(len(dirs), dtype=bool)
    for start in range(0, u.shape[0], 20000):
        hit |= np.any(u[start:start + 20000] @ dirs.T > cos_limit, axis=0)
    return float(hit.mean())


def _cube_directions() -> np.ndarray:
    d = [(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1) if (i, j, k) != (0, 0, 0)]
    d = np.array(d, dtype=np.float64)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def reference_magnitude_ut(reference: "EarthField | None", mag_ut: np.ndarray, field_ut: float | None = None) -> tuple[float, str]:
    """The field magnitude a fit scales to: explicit `field_ut`, else WMM |F|, else the mean raw norm
    (then the result has the right shape but only approximately the right scale). Returns (µT, source)."""
    if field_ut is not None:
        return float(field_ut), "given"
    if reference is not None:
        return float(reference.total_ut), "wmm"
    return float(np.mean(np.linalg.norm(mag_ut, axis=1))), "mean raw norm (no reference field given)"


# Default acceptance checks of the attitude-independent (full-sphere) fits; each is an option of the fit.
MIN_SAMPLES = 30
MIN_COVERAGE = 0.5            # fraction of the 26 cube directions seen (level turns ≈ 0.3, a tumble ≈ 1)
MAX_RESIDUAL_UT = 1.6         # RMS | |m| − H0 | limit: ArduPilot COMPASS_CAL_FIT default, 16 mgauss (AP_Compass.cpp)
MAX_SIGMA_HARD_UT = 0.5       # 1σ of each hard-iron component (5 mgauss): beyond it the data cannot fix it
MAX_SIGMA_SOFT = 0.01         # 1σ of each soft-iron entry (1 %)
SOFT_IRON_GAIN_RANGE = (0.25, 4.0)  # singular values of soft_iron outside this are not a vehicle's iron
MAX_SPLIT_HARD_UT = 1.0       # first vs second half of the recording: hard iron may differ by this (10 mgauss)
MAX_SPLIT_SOFT = 0.02         # ... and SᵀS by this (2 %): more means the magnetic environment changed


def prepare(data: MagFitInput, reference, field_ut: float | None, min_samples: int, method: str):
    """Common first step: finite rows, the reference magnitude, the sample count check.
    Returns (mag (n,3), H0 µT, quality dict) or a refused MagFitResult."""
    good = finite_rows(data.mag_ut)
    mag = np.asarray(data.mag_ut[good])
    quality: dict = {"n_samples": int(len(data)), "n_used": int(mag.shape[0]), "n_dropped_non_finite": int((~good).sum())}
    if mag.shape[0] < min_samples:
        dropped = quality["n_dropped_non_finite"]
        return refuse(method, f"too few samples: {mag.shape[0]} usable" + (f" ({dropped} non-finite dropped)" if dropped
                      else "") + f", need at least {min_samples}: record longer while turning the sensor", **quality)
    h0, source = reference_magnitude_ut(reference, mag, field_ut)
    if not (h0 > 0 and math.isfinite(h0)):
        return refuse(method, f"reference field magnitude {h0!r} µT is not positive: check --lat/--lon/--alt-m "
                      "(or the field given)", **quality)
    quality["field_ut"] = h0
    quality["field_source"] = source
    quality["raw_coverage"] = direction_coverage(mag - mag.mean(axis=0))
    return mag, h0, quality


def centred(mag: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """(centre, scale, (mag − centre)/scale): the thesis's regressions are solved in these coordinates. The
    algebra is invariant to a shift of origin and a common scale (b and k map back exactly, the angles do not
    change), and the normal equations stay well conditioned (raw µT² terms reach 10⁴)."""
    centre = mag.mean(axis=0)
    scale = float(np.mean(np.linalg.norm(mag - centre, axis=1))) or 1.0
    return centre, scale, (mag - centre) / scale


def conditioning_refusal(method: str, regressors: np.ndarray, max_condition: float, quality: dict) -> MagFitResult | None:
    """Records the condition number of the column-normalised regressors in `quality`; a refusal when it is
    above max_condition (an axis the turns never moved through the field), else None."""
    cond = float(np.linalg.cond(regressors / np.linalg.norm(regressors, axis=0)))
    quality["condition_number"] = cond
    if np.isfinite(cond) and cond <= max_condition:
        return None
    return refuse(method, f"the regression is ill-conditioned (condition number {cond:.3g} > {max_condition:.3g}): "
                  "the turns do not move every axis through the field; rotate about all three axes", **quality)


def parameter_sigmas(model: MagModel, mag_ut: np.ndarray, field_ut: float, params: str) -> tuple[np.ndarray, np.ndarray]:
    """1σ of the hard iron (µT) and of the free soft-iron entries from the magnitude residual's Jacobian
    at the solution (Gauss–Newton covariance, σ² = residual variance). `params`: 'diag' (two-step),
    'upper' (three-step, upper triangle), 'sym' (ellipsoid, symmetric), 'full'."""
    d = mag_ut - model.hard_iron_ut
    v = d @ model.soft_iron.T
    norm = np.linalg.norm(v, axis=1)
    n = v / norm[:, None]
    r = norm - field_ut
    cols = [-(n @ model.soft_iron)]  # ∂r/∂h, (m, 3)
    if params == "diag":
        idx = [(0, 0), (1, 1), (2, 2)]
    elif params == "upper":
        idx = [(i, j) for i in range(3) for j in range(i, 3)]
    elif params == "sym":
        idx = [(i, j) for i in range(3) for j in range(i, 3)]
    else:
        idx = [(i, j) for i in range(3) for j in range(3)]
    soft_cols = []
    for i, j in idx:
        c = n[:, i] * d[:, j]
        if params == "sym" and i != j:
            c = c + n[:, j] * d[:, i]
        soft_cols.append(c)
    jac = np.column_stack(cols + [np.column_stack(soft_cols)])
    dof = max(len(r) - jac.shape[1], 1)
    s2 = float(r @ r) / dof
    try:
        cov = np.linalg.inv(jac.T @ jac) * s2
        sig = np.sqrt(np.maximum(np.diag(cov), 0.0))
    except np.linalg.LinAlgError:
        sig = np.full(jac.shape[1], np.inf)
    return sig[:3], sig[3:]


def assess(method: str, model: MagModel, mag_ut: np.ndarray, field_ut: float, quality: dict, *, params: str,
           min_coverage: float = MIN_COVERAGE, max_residual_ut: float = MAX_RESIDUAL_UT,
           max_sigma_hard_ut: float = MAX_SIGMA_HARD_UT, max_sigma_soft: float = MAX_SIGMA_SOFT,
           refit: Callable[[np.ndarray], MagModel] | None = None, max_split_hard_ut: float = MAX_SPLIT_HARD_UT,
           max_split_soft: float = MAX_SPLIT_SOFT) -> MagFitResult:
    """Residuals and acceptance checks common to the magnitude-based fits; a refused result if one fails.

    With `refit` (the method's fit on a subset of rows, returning a MagModel or raising ValueError), the
    first and second halves of the recording are fitted separately when each covers the sphere well
    enough: if they disagree, the field changed during the recording (a magnet, a ferrous object moved, a
    current switched) — a disturbance the whole-record fit can partly absorb into its parameters."""
    resid = magnitude_residuals(model, mag_ut, field_ut)
    rms = float(np.sqrt(np.mean(resid**2)))
    cal = model.apply(mag_ut)
    coverage = direction_coverage(cal)
    sig_h, sig_s = parameter_sigmas(model, mag_ut, field_ut, params)
    gains = np.linalg.svd(model.soft_iron, compute_uv=False)
    quality.update(
        residual_rms_ut=rms,
        residual_max_ut=float(np.max(np.abs(resid))),
        coverage=coverage,
        sigma_hard_iron_ut=sig_h.tolist(),
        sigma_soft_iron=sig_s.tolist(),
        soft_iron_singular_values=gains.tolist(),
    )
    reasons = _check_limits(rms, coverage, sig_h, sig_s, gains, min_coverage, max_residual_ut, max_sigma_hard_ut,
                            max_sigma_soft)
    if refit is not None and not reasons:
        split = _split_halves(model, mag_ut, cal, refit, min_coverage)
        quality["split_halves"] = split
        if split.get("hard_iron_diff_ut", 0.0) > max_split_hard_ut or split.get("soft_iron_diff", 0.0) > max_split_soft:
            reasons.append(
                f"the first and second halves of the recording give different calibrations (hard iron "
                f"{split['hard_iron_diff_ut']:.2f} µT apart, soft iron {split['soft_iron_diff']:.3f}): the magnetic "
                "environment changed during the recording (a magnet or a ferrous object moved, a current switched)")
    if reasons:
        quality["rejected_model"] = model.to_dict()
        return MagFitResult(MagModel.identity(), rms, method, quality, "; ".join(reasons))
    return MagFitResult(model, rms, method, quality, None)


def _check_limits(rms: float, coverage: float, sig_h: np.ndarray, sig_s: np.ndarray, gains: np.ndarray,
                  min_coverage: float, max_residual_ut: float, max_sigma_hard_ut: float,
                  max_sigma_soft: float) -> list[str]:
    """Why a fit is refused (ArduPilot-style limits: coverage, residual, parameter 1σ, physical soft-iron gains),
    each with what to do about it; empty when it passes."""
    reasons = []
    if coverage < min_coverage:
        reasons.append(f"orientation coverage {coverage:.0%} < {min_coverage:.0%}: turn the sensor through more "
                       "attitudes (for a vehicle that cannot be tilted use the backstepping method)")
    if rms > max_residual_ut:
        reasons.append(f"residual {rms:.2f} µT RMS is over {max_residual_ut} µT: the model does not describe the "
                       "data (a magnetic disturbance or a moving magnet during the calibration?)")
    if not np.all(sig_h <= max_sigma_hard_ut):
        reasons.append(f"hard iron poorly determined (1σ up to {np.max(sig_h):.2f} µT > {max_sigma_hard_ut} µT, "
                       f"coverage {coverage:.0%}): turn the sensor through more attitudes, slowly")
    if not np.all(sig_s <= max_sigma_soft):
        reasons.append(f"soft iron poorly determined (1σ up to {np.max(sig_s):.3f} > {max_sigma_soft}, coverage "
                       f"{coverage:.0%}): turn the sensor through more attitudes, or use --method two-step "
                       "(fewer parameters)")
    lo, hi = SOFT_IRON_GAIN_RANGE
    if gains.min() < lo or gains.max() > hi:
        reasons.append(f"soft-iron gains {gains.min():.2f}…{gains.max():.2f} outside {lo}…{hi}: not physical; a "
                       "magnet or steel right at the sensor, or a wrong reference field (--lat/--lon)?")
    return reasons


def _split_halves(model: MagModel, mag_ut: np.ndarray, cal: np.ndarray, refit, min_coverage: float) -> dict:
    """Fit each half of the recording (in time) and compare with each other."""
    half = mag_ut.shape[0] // 2
    parts = (slice(0, half), slice(half, None))
    cover = [direction_coverage(cal[p]) for p in parts]
    if min(cover) < min_coverage or half < MIN_SAMPLES:
        return {"checked": False, "why": f"a half covers too little ({min(cover):.0%}) or has too few samples"}
    models = []
    for p in parts:
        try:
            models.append(refit(mag_ut[p]))
        except (ValueError, np.linalg.LinAlgError) as exc:
            return {"checked": False, "why": f"a half could not be fitted ({exc})"}
    a, b = models
    gram_a, gram_b = a.soft_iron.T @ a.soft_iron, b.soft_iron.T @ b.soft_iron
    return {
        "checked": True,
        "hard_iron_diff_ut": float(np.max(np.abs(a.hard_iron_ut - b.hard_iron_ut))),
        "soft_iron_diff": float(np.max(np.abs(gram_a - gram_b))),
    }
