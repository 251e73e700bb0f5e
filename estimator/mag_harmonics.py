"""The heading error a magnetometer calibration leaves, as five filter states: a Fourier series in the vehicle's
magnetic heading ψ,

    e(ψ) = c0 + c1·cos ψ + s1·sin ψ + c2·cos 2ψ + s2·sin 2ψ            (rad, the field azimuth's error)

Why states and not noise: what a calibration leaves is residual iron and a levelling error. A hard iron b left in
the body frame turns with the vehicle, so on a level vehicle it turns the field's azimuth by (b × ĥ)/H, once per
turn (c1, s1); a soft-iron error (I + D) scales and couples the horizontal axes, twice per turn (c2, s2), its
antisymmetric part and a magnetometer-to-IMU misalignment about down a constant (c0); a levelling error β of the
calibration tilts the measured vertical, β·tan(dip) once per turn. These are a ship's compass deviation
coefficients A, B, C, D, E (NGA Pub. 226, Handbook of Magnetic Compass Adjustment). While the vehicle
holds a heading e is a bias, not noise: fused as white noise with a short correlation time, the filter's heading σ
falls below it (docs/estimator.md "A calibrated magnetometer"). As states with the calibration's stated 1σ for a
prior, the filter knows the error stays while the heading holds, separates the harmonic part as the vehicle turns
(the gyro measures the heading change the harmonics follow), and learns c0 only from what else observes the
heading (the GNSS velocity in accelerations).

The prior: at any one heading Var e(ψ) = v0 + v1 + v2 when c0 has v0, c1 and s1 each v1, c2 and s2 each v2
(cos² + sin² = 1), so the calibration's heading variance σ² is split as v0 = f0·σ² (the constant's share) and the
rest 2 : 1 between the once- and twice-per-turn terms (hard iron, the usual largest residual, once per turn).

ArduPilot EKF3 and PX4 EKF2 carry the same error as body-frame magnetic field bias states (three, µT) fused with
the field's three components; five heading harmonics are what a heading-only measurement (this filter's) can
separate, and they also hold the soft iron's and the misalignment's part, which a body-frame bias cannot.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

N_MAG_HARMONICS = 5
"""c0, c1, s1, c2, s2 (the order of the state and of `harmonic_basis`)."""

ONCE_PER_TURN_SHARE = 2.0 / 3.0
"""The heading-dependent part of the prior variance (1 − f0) goes this much to c1, s1 and the rest to c2, s2."""


@njit(cache=True)
def harmonic_basis(psi_rad):
    """∂e/∂(c0, c1, s1, c2, s2) at the magnetic heading ψ: (1, cos ψ, sin ψ, cos 2ψ, sin 2ψ)."""
    c = math.cos(psi_rad)
    s = math.sin(psi_rad)
    return 1.0, c, s, c * c - s * s, 2.0 * s * c


@njit(cache=True)
def heading_error_rad(coeffs, psi_rad):
    """e(ψ) of the coefficients `coeffs` (N_MAG_HARMONICS,), rad."""
    b0, b1, b2, b3, b4 = harmonic_basis(psi_rad)
    return b0 * coeffs[0] + b1 * coeffs[1] + b2 * coeffs[2] + b3 * coeffs[3] + b4 * coeffs[4]


def prior_variances_rad2(calibration_sigma_rad: float, offset_share: float,
                         carried_once_per_turn_sigma_rad: float = 0.0) -> np.ndarray:
    """The prior variance of each coefficient (c0, c1, s1, c2, s2), rad², for a calibration whose heading error is
    σ (1σ at any heading): c0 the offset share f0 of σ², c1 and s1 each `ONCE_PER_TURN_SHARE` of the rest, c2 and
    s2 each what is left; their sum at any heading is σ².

    `carried_once_per_turn_sigma_rad` σ_t: a part of σ that other states carry (the calibration frame's tilt,
    tan(dip)·ε: mag_frame_tilt.py), once per turn with σ_t² on each of cos ψ and sin ψ, so σ_t² at any heading.
    It is taken out of c1 and s1; what they hold less than σ_t² (the split is a generic prior: the tilt can be most
    of a calibration's error) out of the other heading-dependent terms c2, s2, and only what is left then out of
    the constant c0. The sum at any heading is σ² − σ_t², with the tilt's σ_t² the calibration's σ² again (its
    prediction added σ_t² in quadrature, levelling_error.py)."""
    var = float(calibration_sigma_rad) ** 2
    f0 = min(max(float(offset_share), 0.0), 1.0)
    once = (1.0 - f0) * ONCE_PER_TURN_SHARE * var
    twice = (1.0 - f0) * (1.0 - ONCE_PER_TURN_SHARE) * var
    offset = f0 * var
    left = float(carried_once_per_turn_sigma_rad) ** 2 if carried_once_per_turn_sigma_rad > 0.0 else 0.0
    if left > 0.0:      # at any heading each pair counts once (cos² + sin² = 1), the constant once
        taken = min(once, left)
        once, left = once - taken, left - taken
        taken = min(twice, left)
        twice, left = twice - taken, left - taken
        offset = max(0.0, offset - left)
    return np.array([offset, once, once, twice, twice])


def prior_from_heading_rows(rows: np.ndarray, psi_rad: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """The coefficients' covariance (5×5, rad²) of a heading error e(ψ) = a(ψ)·δx with δx ~ (0, cov): `rows`
    holds a(ψ) at the magnetic headings `psi_rad` (one row a heading, evenly spread over the turn), fitted by least
    squares onto the basis. A learned iron's error on a level vehicle is such a series (to first order in its
    error: the hard iron's once per turn, the soft iron's constant and twice per turn, the module docstring), so
    its coefficients are correlated as the learner's covariance says and their sum at any heading keeps
    a(ψ) · cov · a(ψ)ᵀ."""
    psi = np.asarray(psi_rad, dtype=float)
    basis = np.stack([np.ones_like(psi), np.cos(psi), np.sin(psi), np.cos(2.0 * psi), np.sin(2.0 * psi)], axis=1)
    coeffs = np.linalg.lstsq(basis, np.asarray(rows, dtype=float), rcond=None)[0]     # (5, len(δx))
    prior = coeffs @ np.asarray(cov, dtype=float) @ coeffs.T
    return 0.5 * (prior + prior.T)
