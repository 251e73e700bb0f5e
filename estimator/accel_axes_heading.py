"""The heading error the accelerometer's own axes leave in a GNSS-aided heading, as the published yaw 1σ must
carry it.

With GNSS, ins observes its heading through the horizontal specific force: in a turn the centripetal
acceleration a_c lies along the body y axis, and a yaw error δψ shows as a force a_c·δψ along body x; braking or
accelerating a_x along x shows a yaw error as a_x·δψ along y. An accelerometer whose x axis leans towards y by
m_xy (its cross-axis misalignment, Groves 2nd ed. eq. 4.16: f_meas = (I + diag(s) + M) f + b) measures a_c·m_xy
along x in the same turn: exactly what a yaw error of m_xy would give, whatever a_c is. So the GNSS-aided heading
is the accelerometer's x–y axes' heading, off the body's by m_xy after turns and by m_yx after braking — an error
that no amount of GNSS data removes (the filter has no accelerometer misalignment states: only a body-frame bias)
and that the filter's covariance does not contain. The published 1σ therefore adds it as a "consider" term
(Schmidt), independent of the filter's own error: σ_pub² = σ_filter² + σ_m², σ_m the accelerometer's x–y
misalignment 1σ (InsParams.accel_axes_heading_sigma_rad). The accelerometer's scale errors do not enter: along
the force's own direction they change its size, not the heading it implies.

Measured with the simulator's truth (docs/estimator.md "The accelerometer's axes in the GNSS heading"): on the
car with perfect sensors and GNSS but for m_xy, the heading error follows m_xy and stays.
"""

from __future__ import annotations

import math


def accel_axes_heading_variance_rad2(accel_axes_sigma_rad: float) -> float:
    """The heading variance (rad²) a GNSS-aided heading's published σ adds in quadrature for the accelerometer's
    x–y misalignment 1σ `accel_axes_sigma_rad` (module docstring); 0 for a σ that is not finite and > 0."""
    s = float(accel_axes_sigma_rad)
    return s * s if math.isfinite(s) and s > 0.0 else 0.0
