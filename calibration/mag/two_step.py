"""The thesis's two-step magnetometer calibration (the ADIS16405 AHRS
thesis; docs/calibration.md): hard iron b and per-axis
scale k, no misalignment (6 parameters), attitude-independent.

Model: H0² = Σ_i ((B_i − b_i)/k_i)², an axis-aligned ellipsoid. Multiplying by k_x² and rearranging
gives one linear equation per sample:

    −B_x² = S1·B_x + S2·B_y² + S3·B_y + S4·B_z² + S5·B_z + S6

solved by least squares for S (step 1); then b and k follow from S (step 2, `inverse_mapping`).
"""

from __future__ import annotations

import numpy as np

from .acceptance import assess, centred, conditioning_refusal, prepare
from .fit_types import MagFitInput, MagFitResult, refuse
from ..models import MagModel

METHOD = "two-step"


def regressors(mag_ut: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(z, H) of the regression above: z(k) = −B_x², h(k) = [B_x, B_y², B_y, B_z², B_z, 1]."""
    bx, by, bz = mag_ut[:, 0], mag_ut[:, 1], mag_ut[:, 2]
    h = np.column_stack([bx, by * by, by, bz * bz, bz, np.ones_like(bx)])
    return -bx * bx, h


def forward_mapping(b: np.ndarray, k: np.ndarray, field_ut: float) -> np.ndarray:
    """S from (b, k, H0) — the inverse of `inverse_mapping`, used by the tests."""
    bx, by, bz = b
    kx, ky, kz = k
    s2, s4 = kx**2 / ky**2, kx**2 / kz**2
    return np.array([-2 * bx, s2, -2 * s2 * by, s4, -2 * s4 * bz, bx**2 + s2 * by**2 + s4 * bz**2 - kx**2 * field_ut**2])


def inverse_mapping(s: np.ndarray, field_ut: float) -> tuple[np.ndarray, np.ndarray]:
    """(b, k) from S: b_x = −S1/2, b_y = −S3/(2 S2), b_z = −S5/(2 S4), then k from H0. Raises ValueError when S does not describe an ellipsoid."""
    s1, s2, s3, s4, s5, s6 = s
    if not (s2 > 0 and s4 > 0):
        raise ValueError(f"S2 = {s2:.4g}, S4 = {s4:.4g}: not an ellipsoid (need both > 0)")
    bx, by, bz = -s1 / 2, -s3 / (2 * s2), -s5 / (2 * s4)
    kx2 = (bx**2 + s2 * by**2 + s4 * bz**2 - s6) / field_ut**2
    if not kx2 > 0:
        raise ValueError(f"k_x² = {kx2:.4g} ≤ 0: not an ellipsoid")
    kx = np.sqrt(kx2)
    return np.array([bx, by, bz]), np.array([kx, np.sqrt(kx2 / s2), np.sqrt(kx2 / s4)])


def solve_model(mag: np.ndarray, field_ut: float) -> MagModel:
    """Steps 1 and 2 on `mag` (n, 3) → MagModel. Raises ValueError when the data are not an ellipsoid."""
    centre, scale, u = centred(mag)
    z, h = regressors(u)
    s, *_ = np.linalg.lstsq(h, z, rcond=None)
    b_u, k_u = inverse_mapping(s, 1.0)
    return MagModel.from_thesis(centre + scale * b_u, k_u * scale / field_ut)


def fit_two_step(data: MagFitInput, reference=None, *, field_ut: float | None = None, min_samples: int = 30,
                 max_condition: float = 1e7, **checks) -> MagFitResult:
    """Two-step fit of `data.mag_ut`. `reference` (EarthField) or `field_ut` give H0; `checks` go to
    `acceptance.assess` (min_coverage, max_sigma_hard_ut, max_sigma_soft, ...)."""
    prep = prepare(data, reference, field_ut, min_samples, METHOD)
    if isinstance(prep, MagFitResult):
        return prep
    mag, h0, quality = prep
    refusal = conditioning_refusal(METHOD, regressors(centred(mag)[2])[1], max_condition, quality)
    if refusal is not None:
        return refusal
    try:
        model = solve_model(mag, h0)
    except ValueError as exc:
        return refuse(METHOD, f"the data do not describe an ellipsoid ({exc}): too little rotation, or a disturbance that "
                      "moved (a magnet, steel, a current); record again away from it, turning through all attitudes", **quality)
    quality["scale_k"] = (1.0 / np.diag(model.soft_iron)).tolist()
    return assess(METHOD, model, mag, h0, quality, params="diag", refit=lambda m: solve_model(m, h0), **checks)
