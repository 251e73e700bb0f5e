"""Full ellipsoid magnetometer fit: hard iron h and a symmetric soft iron S (9 parameters), attitude-independent.

1. Algebraic guess: the general quadric xᵀAx + 2pᵀx + d = 0 through the (centred, scaled) samples, the
   right singular vector of the design matrix with the smallest singular value; centre −A⁻¹p, shape A/κ.
2. Levenberg–Marquardt refinement (scipy least_squares, method 'lm') of the geometric-ish residual
   r = |S(B − h)| − H0 over (h, upper triangle of the symmetric S), with the analytic Jacobian.

S is symmetric because the magnitude cannot see a rotation: any S' = R·S fits equally well. Choosing the
symmetric one is the smallest correction (ArduPilot's CompassCalibrator makes the same choice); the heading
effect of the missing rotation is the constant deviation "coefficient A" of the compass-deviation
series A + B sin ψ + C cos ψ + D sin 2ψ + E cos 2ψ (Bowditch, "The American Practical Navigator"), which only a
heading reference removes.
"""

from __future__ import annotations

import numpy as np

from .acceptance import MIN_COVERAGE, assess, prepare
from .fit_types import MagFitInput, MagFitResult, refuse
from ..models import MagModel

METHOD = "ellipsoid"
_UPPER = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]


def algebraic_fit(mag_ut: np.ndarray, field_ut: float) -> MagModel:
    """The quadric fit (step 1). Raises ValueError when the best quadric is not an ellipsoid."""
    centre = mag_ut.mean(axis=0)
    scale = float(np.mean(np.linalg.norm(mag_ut - centre, axis=1))) or 1.0
    u = (mag_ut - centre) / scale
    x, y, z = u.T
    d = np.column_stack([x * x, y * y, z * z, 2 * x * y, 2 * x * z, 2 * y * z, 2 * x, 2 * y, 2 * z, np.ones_like(x)])
    _, _, vt = np.linalg.svd(d, full_matrices=False)
    a_, b_, c_, h_, g_, f_, p_, q_, r_, d_ = vt[-1]
    a = np.array([[a_, h_, g_], [h_, b_, f_], [g_, f_, c_]])
    try:
        c0 = -np.linalg.solve(a, np.array([p_, q_, r_]))
    except np.linalg.LinAlgError:
        raise ValueError("the quadric through the samples is degenerate") from None
    kappa = c0 @ a @ c0 - d_
    m = a / kappa
    w, v = np.linalg.eigh(m)
    if not np.all(w > 0):
        raise ValueError(f"the best quadric is not an ellipsoid (eigenvalues {np.round(w, 4).tolist()})")
    soft = field_ut / scale * (v * np.sqrt(w)) @ v.T  # H0 · sqrtm(M_u) / scale
    return MagModel(centre + scale * c0, soft)


def _pack(model: MagModel) -> np.ndarray:
    s = model.soft_iron
    return np.concatenate([model.hard_iron_ut, [s[i, j] for i, j in _UPPER]])


def _unpack(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    s = np.empty((3, 3))
    for value, (i, j) in zip(p[3:], _UPPER):
        s[i, j] = s[j, i] = value
    return p[:3], s


def refine(mag_ut: np.ndarray, field_ut: float, initial: MagModel, max_nfev: int = 200):
    """Levenberg–Marquardt on r = |S(B − h)| − H0 (step 2). Returns (MagModel, scipy result)."""
    from scipy.optimize import least_squares

    def residual(p):
        h, s = _unpack(p)
        return np.linalg.norm((mag_ut - h) @ s.T, axis=1) - field_ut

    def jacobian(p):
        h, s = _unpack(p)
        d = mag_ut - h
        v = d @ s.T
        n = v / np.linalg.norm(v, axis=1)[:, None]
        cols = [-(n @ s)]
        for i, j in _UPPER:
            cols.append((n[:, i] * d[:, j] + (n[:, j] * d[:, i] if i != j else 0.0))[:, None])
        return np.hstack(cols)

    sym = 0.5 * (initial.soft_iron + initial.soft_iron.T)
    p0 = _pack(MagModel(initial.hard_iron_ut, sym))
    sol = least_squares(residual, p0, jac=jacobian, method="lm", max_nfev=max_nfev, x_scale="jac")
    h, s = _unpack(sol.x)
    return MagModel(h, s), sol


def fit_ellipsoid(data: MagFitInput, reference=None, *, field_ut: float | None = None, min_samples: int = 30,
                  **checks) -> MagFitResult:
    """Ellipsoid fit of `data.mag_ut` (algebraic guess + LM). `reference` (EarthField) or `field_ut` give H0;
    `checks` go to `acceptance.assess`."""
    prep = prepare(data, reference, field_ut, min_samples, METHOD)
    if isinstance(prep, MagFitResult):
        return prep
    mag, h0, quality = prep
    try:
        initial = algebraic_fit(mag, h0)
        quality["initial"] = "algebraic quadric"
    except ValueError as exc:
        # A hyperboloid or a degenerate quadric: the samples span too little of the sphere for the
        # algebraic step; start LM from a sphere at the data centroid and let the checks judge the result.
        quality["initial"] = f"sphere at the centroid ({exc})"
        centre = mag.mean(axis=0)
        radius = float(np.mean(np.linalg.norm(mag - centre, axis=1)))
        initial = MagModel(centre, np.eye(3) * h0 / radius)
    quality["initial_hard_iron_ut"] = initial.hard_iron_ut.tolist()
    try:
        model, sol = refine(mag, h0, initial)
    except (ValueError, np.linalg.LinAlgError) as exc:
        return refuse(METHOD, f"the Levenberg–Marquardt refinement failed ({exc}): turn the sensor through more "
                      "attitudes, or try --method two-step", **quality)
    quality.update(lm_status=int(sol.status), lm_evaluations=int(sol.nfev))
    if sol.status <= 0:
        reason = f"the Levenberg–Marquardt refinement did not converge ({sol.message})"
        if quality["raw_coverage"] < checks.get("min_coverage", MIN_COVERAGE):
            reason += f"; orientation coverage only {quality['raw_coverage']:.0%}: turn the sensor through more attitudes"
        return refuse(METHOD, reason, **quality)
    def refit(m: np.ndarray) -> MagModel:
        return refine(m, h0, algebraic_fit(m, h0))[0]

    return assess(METHOD, model, mag, h0, quality, params="sym", refit=refit, **checks)
