"""The tilt of a calibrated magnetometer's frame against the body, as two filter states: a small rotation
ε = (ε_x, ε_y) of the calibration's frame about the body's x and y axes.

Why: a back-stepping calibration takes its vertical from a levelling (the accelerometer, or the GNSS-aided ins
smoothed over the run: calibration/mag/levelling_error.py) that cannot tell a horizontal accelerometer bias from a
tilt, so the calibrated magnetometer reads the field in a frame tilted by that levelling's body-fixed error, one
draw for the whole calibration. The heading row (ins_core._mag_heading_row) reads a tilt error along magnetic north
as tan(dip) times as much heading error; assuming the body's vertical, in a full turn it takes the frame's tilt
turning against the field for the magnetometer confirming the filter's own tilt, which carries the same kind of
accelerometer-bias tilt, and shrinks the tilt σ while the error stays (docs/estimator.md, "A calibrated
magnetometer's frame tilt as states").

The measurement: the calibration gives m_cal = (I + [ε×]) m_b. Rotated to NED with the estimated attitude,
C_est = (I − [δθ×]) C, it is m − δθ × m + (C ε) × m = m − (δθ − C ε) × m: the magnetometer sees the attitude
error δθ − C ε. The row's entries h_θ on δθ (N, E, D) therefore give ∂α/∂ε_k = −Σ_i h_θ,i C_ik on the frame
tilt (k = body x, y; the tilt about the body's z is a heading offset, the harmonic c0's).

The prior: the calibration's own statement of its levelling's body-fixed tilt, 1σ per axis
(calibration/heading_trust.calibration_frame_tilt_sigma_rad); a calibration levelled with the true attitude (the
simulator's, a bench calibration) states none and the states stay off. They are a constant of the calibration:
no random walk, learnt only while the GNSS holds the tilt (as the harmonic states, the same reason).

The tilt is the bias the calibration's levelling left, ε = (b̃_y, −b̃_x)/g with b̃ = b − b̂_cal (the levelled
vertical of an accelerometer reading f = b − g e_z leans by b_h/g), and the filter's own bias error δb_a = b − b̂
holds the same b: the levelling's estimate being uncorrelated with its error, Cov(b̃, b) = Var(b̃) = (g σ)², so
with the filter's bias prior σ_b (at start-up, when b̂ knows nothing the levelling knew) ε = G δb_a + w with
G_x,y = k_y/g, G_y,x = −k_x/g, k = (g σ)²/σ_b² (≤ 1) and w the rest of σ² (`accel_bias_share`). The
magnetometer then sees δθ − C ε, in which the part of the tilt that is the accelerometer's bias (the part GNSS
velocity cannot see on a near-level vehicle) cancels as much as the two levellings share."""

from __future__ import annotations

import numpy as np
from numba import njit

from ahrsd.core.angles import STANDARD_GRAVITY_M_S2

N_MAG_FRAME_TILT = 2
"""ε_x, ε_y (rad, about the body's x and y axes; the order of the state)."""


@njit(cache=True)
def frame_tilt_partials(h_n, h_e, h_d, c):
    """∂α/∂(ε_x, ε_y) for the heading row whose entries on the NED attitude error are (h_n, h_e, h_d), with the
    attitude C_b^n `c` as `kernel_rotations.dcm`'s row-major 9-tuple: −h_θ·C e_x and −h_θ·C e_y."""
    c00, c01, c02, c10, c11, c12, c20, c21, c22 = c
    return (-(h_n * c00 + h_e * c10 + h_d * c20),
            -(h_n * c01 + h_e * c11 + h_d * c21))


def accel_bias_share(sigma_rad: float, accel_bias_var_m2_s4) -> np.ndarray:
    """G (2 × 3): the frame tilt's regression on the filter's accelerometer-bias error, ε = G δb_a + w, for a
    calibration stating σ (rad per axis) and the filter's bias variances (m²/s⁴, body x, y, z) now; see the
    module docstring. An axis whose bias variance is below (g σ)² shares all of it (k = 1)."""
    g = STANDARD_GRAVITY_M_S2
    var = np.asarray(accel_bias_var_m2_s4, dtype=float)
    k = [min(1.0, (g * sigma_rad) ** 2 / v) if v > 0.0 else 0.0 for v in var[:2]]
    gain = np.zeros((N_MAG_FRAME_TILT, 3))
    gain[0, 1] = k[1] / g
    gain[1, 0] = -k[0] / g
    return gain
