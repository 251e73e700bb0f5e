"""The roll and pitch error the accelerometer's own axes leave in ins's tilt, as the published roll and pitch 1σ
must carry it.

ins levels its attitude on the specific force the accelerometer measures (with GNSS: on the difference between
it and the acceleration the fixes show). An accelerometer whose axes lean on one another (its cross-axis
misalignment M, Groves 2nd ed. eq. 4.16: f_meas = (I + diag(s) + M) f + b) reads f_j + m_jk f_k: the y axis
leaning towards z reads −g·m_yz at rest, a lateral "bias" that a roll of m_yz gives too, and that changes as the
boat heels (−g·m_yz·cos φ), so the filter's body-frame bias state does not hold it. The filter has no misalignment
state for the accelerometer and its covariance does not contain this error; the published 1σ adds it as a
"consider" term (Schmidt), independent of the filter's own error, as accel_axes_heading.py does for the heading:
σ_pub² = σ_filter² + Σ_{j≠k} (∂angle/∂f_j · f_k)² σ_m², σ_m the misalignment's 1σ per off-diagonal element
(InsParams.accel_axes_tilt_sigma_rad).

The partials are the levelling's (roll = atan2(−f_y, −f_z), pitch = atan2(f_x, √(f_y² + f_z²))), first order in
M, taken at the specific force the filter has (`accel_axes_tilt_variance_in_force_rad2`: a turn's, not only
gravity's). At gravity's force alone, f = g (sin θ, −sin φ cos θ, −cos φ cos θ), worked: at heel φ, level pitch,
the roll's error is
m_yz cos²φ − m_zy sin²φ, variance σ_m² (cos⁴φ + sin⁴φ); the pitch's at pitch θ, level roll, −m_xz cos²θ +
m_zx sin²θ. The scale errors' share ((s_y − s_z) sin φ cos φ in roll) vanishes level and is left out, as is the
misalignment the filter's gyro states may have taken up.

Measured with the simulator's truth: docs/estimator.md "The accelerometer's axes in the tilt".
"""

from __future__ import annotations

import math

from numba import njit

ACCEL_MISALIGNMENT_SIGMA_RAD = math.radians(0.1)
"""1σ of each off-diagonal element of the accelerometer's cross-axis misalignment M (rad): an ADIS16405-class
factory alignment, the simulated sensor's figure (simulation/errors.MISALIGN_SIGMA_RAD). One physical figure for
every element, so the default of both consider terms: the tilt's (m_yz, m_xz, …: InsParams.accel_axes_tilt_sigma_rad,
MekfParams.accel_axes_tilt_sigma_rad) and the GNSS heading's (m_xy: InsParams.accel_axes_heading_sigma_rad,
accel_axes_heading.py). Kept as two parameters, as a sensor whose figure is known per axis may set them apart."""


@njit(cache=True)
def accel_axes_tilt_variance_in_force_rad2(c, fn, fe, fd, accel_axes_sigma_rad):
    """(roll, pitch) variance (rad²) the accelerometer's misalignment (1σ `accel_axes_sigma_rad` per off-diagonal
    element) leaves in a tilt levelled on the specific force f^n = (fn, fe, fd) (NED, any scale: the low-passed
    force the filter has), at the attitude C_b^n `c` (`kernel_rotations.dcm`'s row-major 9-tuple). Used by mekf,
    whose levelling is that force's direction (mekf_core._fill_outputs).

    The misalignment m_jk adds m_jk f̂_k along body axis j: across f̂ that is the rotation δθ = f̂ × (M f̂) of the
    measured force, which the levelled attitude takes (its part about f̂ changes no force). An angle whose row on a
    body rotation is a (ZYX Euler rates: roll (1, sin φ tan θ, cos φ tan θ), pitch (0, cos φ, −sin φ)) then reads
    a·(f̂ × e_j) f̂_k m_jk = (a × f̂)_j f̂_k m_jk, so its variance is σ_m² Σ_j (a × f̂)_j² (1 − f̂_j²) (Σ_{k≠j} f̂_k²).
    At gravity's force it is the levelling's partials of the module docstring; in a coordinated turn,
    where f̂ stays on the body's z axis, the roll's is σ_m² at any bank. A force of no size: gravity's direction.
    (0, 0) for a σ that is not > 0."""
    s = accel_axes_sigma_rad
    if not s > 0.0:
        return 0.0, 0.0
    c00, c01, c02, c10, c11, c12, c20, c21, c22 = c
    fx = c00 * fn + c10 * fe + c20 * fd          # the force in the body: (C_b^n)ᵀ f^n
    fy = c01 * fn + c11 * fe + c21 * fd
    fz = c02 * fn + c12 * fe + c22 * fd
    norm = math.sqrt(fx * fx + fy * fy + fz * fz)
    if not norm > 0.0:
        fx, fy, fz, norm = -c20, -c21, -c22, 1.0     # gravity's: minus the body's down
    ux, uy, uz = fx / norm, fy / norm, fz / norm
    cos2 = c21 * c21 + c22 * c22                 # cos²θ (sin φ cos θ = c21, cos φ cos θ = c22, sin θ = −c20)
    if cos2 < 1e-18:                             # pitched ±90°: roll is undefined, and so is its error
        return math.inf, s * s
    tan_over_cos = -c20 / cos2
    cos_pitch = math.sqrt(cos2)
    var = [0.0, 0.0]
    for i in range(2):
        if i == 0:
            ax, ay, az = 1.0, c21 * tan_over_cos, c22 * tan_over_cos        # roll's row
        else:
            ax, ay, az = 0.0, c22 / cos_pitch, -c21 / cos_pitch             # pitch's row
        wx = ay * uz - az * uy                   # a × f̂
        wy = az * ux - ax * uz
        wz = ax * uy - ay * ux
        var[i] = (wx * wx * (1.0 - ux * ux) + wy * wy * (1.0 - uy * uy) + wz * wz * (1.0 - uz * uz)) * s * s
    return var[0], var[1]
