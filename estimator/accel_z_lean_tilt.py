"""The roll and pitch error the accelerometer's z axis leaning towards x and y (m_zx, m_zy) leaves in a tilt the
GNSS has levelled, as the published roll and pitch 1σ must carry it once a fix has aided ins.

ins has a body-frame accelerometer-bias state, so a constant body-frame offset of the specific force tells it
nothing about the tilt: on a level vehicle a forward bias and a pitch are one error (f_x = b_x + g θ). What levels
the aided filter is the vehicle's own horizontal acceleration a, seen in the vertical channel: a pitch error δθ
puts a·δθ into the vertical specific force in the navigation frame (Groves 2nd ed. eq. 14.63, the f^n × δψ term),
which the GNSS's vertical velocity observes. An accelerometer whose z axis leans towards x (its misalignment
element m_zx, Groves eq. 4.16: f_meas = (I + diag(s) + M) f + b) reads m_zx·a on the z axis in that acceleration,
which the filter cannot tell from a pitch of m_zx: after the first accelerations its pitch is the z axis's lean,
and the forward bias follows it (b_x = −g·m_zx, the pair). Likewise a lateral acceleration (a turn) levels the roll
on m_zy. The filter has no state for either element, so its covariance does not hold this error; the published
1σ adds it as a "consider" term (Schmidt), σ_m² on each of roll and pitch (σ_m the misalignment's 1σ per
off-diagonal element, InsParams.accel_axes_tilt_sigma_rad), independent of the x and y axes' lean that
accel_axes_tilt.py adds for the levelling on gravity (which axis's lean a tilt carries depends on how it was
levelled; the filter does not know, so the published σ carries both). Near level (|roll|, |pitch| small against
1 rad), the vehicles that level by accelerating: first order in M.

Measured with the simulator's truth: docs/estimator.md "The accelerometer's z axis in the aided tilt".
"""

from __future__ import annotations

import math


def accel_z_lean_tilt_variance_rad2(accel_axes_sigma_rad: float, ever_aided: bool) -> float:
    """Variance (rad²) the published roll and the published pitch σ each add in quadrature for the z axis's lean
    (module docstring): σ_m² once a fix has aided the filter (`ever_aided`), 0 before (its tilt is then levelled on
    gravity alone, accel_axes_tilt.py) and 0 for a σ that is not finite and > 0."""
    s = float(accel_axes_sigma_rad)
    if not (ever_aided and math.isfinite(s) and s > 0.0):
        return 0.0
    return s * s
