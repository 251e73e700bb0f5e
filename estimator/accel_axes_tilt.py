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

The partials are the levelling's (roll = atan2(−f_y, −f_z), pitch = atan2(f_x, √(f_y² + f_z²))) at the specific
force of gravity alone, f = g (sin θ, −sin φ cos θ, −cos φ cos θ): first order in M, and the vehicle's own
accelerations (small against g on a boat) left out. Worked: at heel φ, level pitch, the roll's error is
m_yz cos²φ − m_zy sin²φ, variance σ_m² (cos⁴φ + sin⁴φ); the pitch's at pitch θ, level roll, −m_xz cos²θ +
m_zx sin²θ. The scale errors' share ((s_y − s_z) sin φ cos φ in roll) vanishes level and is left out, as is the
misalignment the filter's gyro states may have taken up.

Measured with the simulator's truth: docs/estimator.md "The accelerometer's axes in the tilt".
"""

from __future__ import annotations

import math


def accel_axes_tilt_variance_rad2(roll_rad: float, pitch_rad: float,
                                  accel_axes_sigma_rad: float) -> tuple[float, float]:
    """(roll, pitch) variance (rad²) the published tilt σ adds in quadrature at this attitude for the accelerometer's
    misalignment 1σ per off-diagonal element `accel_axes_sigma_rad` (module docstring); (0, 0) for a σ that is not
    finite and > 0."""
    s = float(accel_axes_sigma_rad)
    if not (math.isfinite(s) and s > 0.0):
        return 0.0, 0.0
    sr, cr = math.sin(roll_rad), math.cos(roll_rad)
    sp, cp = math.sin(pitch_rad), math.cos(pitch_rad)
    f0, f1, f2 = sp, -sr * cp, -cr * cp             # gravity's specific force in the body, per g
    r2 = f1 * f1 + f2 * f2                          # cos²θ
    r = math.sqrt(r2)
    if r < 1e-9:                                    # pitched ±90°: roll is undefined, and so is its error
        return math.inf, s * s
    # ∂roll/∂f = (0, f_z, −f_y)/r² and ∂pitch/∂f = (r, −f_x f_y/r, −f_x f_z/r) (per g: |f| = 1); the j axis picks
    # up m_jk · f_k, so each variance sums (∂angle/∂f_j · f_k)² over j ≠ k, written out term by term (j, then k)
    # in that order (∂roll/∂f_x is 0: its two terms add nothing); this runs for every estimate ins builds
    dr1, dr2 = f2 / r2, -f1 / r2
    dp0, dp1, dp2 = r, -f0 * f1 / r, -f0 * f2 / r
    var_roll = (dr1 * f0) ** 2 + (dr1 * f2) ** 2 + (dr2 * f0) ** 2 + (dr2 * f1) ** 2
    var_pitch = (dp0 * f1) ** 2 + (dp0 * f2) ** 2 + (dp1 * f0) ** 2 + (dp1 * f2) ** 2 + (dp2 * f0) ** 2 \
        + (dp2 * f1) ** 2
    return var_roll * s * s, var_pitch * s * s
