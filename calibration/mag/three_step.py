"""The thesis's three-step magnetometer calibration (the ADIS16405 AHRS
thesis; docs/calibration.md): hard iron b, scale k and
the three non-orthogonality angles α_yz, α_zy, α_zx (9 parameters), attitude-independent.

The misalignment T_m^p = C_m'^p · T_m^m' splits into a rotation (unobservable from magnitudes; found by the
alignment step, `alignment.py`) and the upper-triangular T_m^m'. With γ_yz = (k_x/k_y)α_yz,
γ_zy = (k_x/k_z)α_zy, γ_zx = (k_y/k_z)α_zx and the shifted bias b′, each sample gives one linear equation:

    step 1:  z = −B_x²,  h = [B_x, B_y², B_y, B_z², B_z, B_xB_y, B_xB_z, B_yB_z, 1],  z = h·X   (LS for X)
    step 2:  X → (S, γ)         (the thesis's relations, its index typos corrected)
    step 3:  (S, γ) → (b, k, α)

The result is m = T_m^m' · K⁻¹ · (B − b) (the alignment rotation is the identity until `alignment` runs).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .acceptance import assess, centred, conditioning_refusal, prepare
from .fit_types import MagFitInput, MagFitResult, refuse
from .two_step import inverse_mapping
from ..models import MagModel

METHOD = "three-step"


@dataclass(frozen=True)
class ThreeStepParameters:
    """The thesis's intermediate and final quantities (µT for b, b′; dimensionless otherwise)."""

    x: np.ndarray          # X (9), step 1
    s: np.ndarray          # S (6), step 2
    gamma: dict            # γ_yz, γ_zy, γ_zx, step 2
    b_prime: np.ndarray    # b′ (3), step 3
    b: np.ndarray          # hard iron (3)
    k: np.ndarray          # scale (3)
    alpha: dict            # α_yz, α_zy, α_zx (rad)


def regressors(mag_ut: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(z, H) of step 1: z = −B_x², h = [B_x, B_y², B_y, B_z², B_z, B_xB_y, B_xB_z, B_yB_z, 1]."""
    bx, by, bz = mag_ut[:, 0], mag_ut[:, 1], mag_ut[:, 2]
    h = np.column_stack([bx, by * by, by, bz * bz, bz, bx * by, bx * bz, by * bz, np.ones_like(bx)])
    return -bx * bx, h


def x_from_s_gamma(s: np.ndarray, g_yz: float, g_zy: float, g_zx: float) -> np.ndarray:
    """X from S and γ (the definition of X) — the forward direction, for tests."""
    s1, s2, s3, s4, s5, s6 = s
    return np.array([
        s1,
        g_yz**2 + s2,
        s3 - s1 * g_yz,
        g_zy**2 + s2 * g_zx**2 + s4,
        s1 * g_zy - s3 * g_zx + s5,
        -2 * g_yz,
        2 * g_zy,
        -2 * g_yz * g_zy - 2 * s2 * g_zx,
        s6,
    ])


def s_gamma_from_x(x: np.ndarray) -> tuple[np.ndarray, dict]:
    """Step 2 (index typos corrected): X → S (6) and γ."""
    x1, x2, x3, x4, x5, x6, x7, x8, x9 = x
    s1, s6 = x1, x9
    g_yz, g_zy = -0.5 * x6, 0.5 * x7
    s2 = x2 - g_yz**2
    s3 = x3 + s1 * g_yz
    if not s2 > 0:
        raise ValueError(f"S2 = {s2:.4g} ≤ 0: not an ellipsoid")
    g_zx = -(x8 + 2 * g_yz * g_zy) / (2 * s2)
    s4 = x4 - g_zy**2 - s2 * g_zx**2
    s5 = x5 - s1 * g_zy + s3 * g_zx
    if not s4 > 0:
        raise ValueError(f"S4 = {s4:.4g} ≤ 0: not an ellipsoid")
    return np.array([s1, s2, s3, s4, s5, s6]), {"yz": g_yz, "zy": g_zy, "zx": g_zx}


def b_k_alpha_from_s_gamma(s: np.ndarray, gamma: dict, field_ut: float):
    """Step 3: (S, γ) → b′, b, k, α. S has the two-step form with b′ in place of b: b′ and k are the two-step's
    inverse mapping of S."""
    b_prime, k = inverse_mapping(s, field_ut)
    (bpx, bpy, bpz), (kx, ky, kz) = b_prime, k
    alpha = {"yz": gamma["yz"] * ky / kx, "zy": gamma["zy"] * kz / kx, "zx": gamma["zx"] * kz / ky}
    bz = bpz
    by = bpy + gamma["zx"] * bz
    bx = bpx + gamma["yz"] * by - gamma["zy"] * bz
    return b_prime, np.array([bx, by, bz]), k, alpha


def solve(mag_ut: np.ndarray, field_ut: float) -> ThreeStepParameters:
    """The three steps on raw data (no conditioning tricks): the thesis's algorithm as printed."""
    z, h = regressors(mag_ut)
    x, *_ = np.linalg.lstsq(h, z, rcond=None)
    s, gamma = s_gamma_from_x(x)
    b_prime, b, k, alpha = b_k_alpha_from_s_gamma(s, gamma, field_ut)
    return ThreeStepParameters(x, s, gamma, b_prime, b, k, alpha)


def fit_three_step(data: MagFitInput, reference=None, *, field_ut: float | None = None, min_samples: int = 30,
                   max_condition: float = 1e7, alignment: np.ndarray | None = None, **checks) -> MagFitResult:
    """Three-step fit of `data.mag_ut`. `reference` (EarthField) or `field_ut` give H0. `alignment`: a
    C_m'^p from `alignment.fit_alignment` to fold in (default identity). `checks` go to `acceptance.assess`."""
    prep = prepare(data, reference, field_ut, min_samples, METHOD)
    if isinstance(prep, MagFitResult):
        return prep
    mag, h0, quality = prep
    centre, scale, u = centred(mag)
    refusal = conditioning_refusal(METHOD, regressors(u)[1], max_condition, quality)
    if refusal is not None:
        return refusal
    try:
        p = solve(u, 1.0)
    except ValueError as exc:
        return refuse(METHOD, f"the data do not describe an ellipsoid ({exc}): too little rotation, or a disturbance that "
                      "moved (a magnet, steel, a current); record again away from it, turning through all attitudes", **quality)
    b = centre + scale * p.b
    k = p.k * scale / h0
    try:
        model = MagModel.from_thesis(b, k, p.alpha)
    except ValueError as exc:
        return refuse(METHOD, f"non-physical solution ({exc}): turn the sensor through more attitudes; with little "
                      "rotation about one axis use --method two-step", **quality)
    quality.update(scale_k=k.tolist(), alpha_rad={key: float(v) for key, v in p.alpha.items()})
    def refit(m: np.ndarray) -> MagModel:
        c = m.mean(axis=0)
        sc = float(np.mean(np.linalg.norm(m - c, axis=1))) or 1.0
        q = solve((m - c) / sc, 1.0)
        return MagModel.from_thesis(c + sc * q.b, q.k * sc / h0, q.alpha)

    result = assess(METHOD, model, mag, h0, quality, params="upper", refit=refit, **checks)
    if alignment is None or not result.ok:
        return result
    # The rotation does not change any magnitude, so the checks above hold for the aligned model too.
    aligned = MagModel(model.hard_iron_ut, np.asarray(alignment, dtype=np.float64) @ model.soft_iron)
    return replace(result, model=aligned, quality={**result.quality, "alignment": np.asarray(alignment).tolist()})
