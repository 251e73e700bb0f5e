"""The heading error a magnetometer calibration leaves, as the published yaw 1σ of a magnetometer-held heading
without GNSS must carry it.

Without GNSS (mekf; ins before its first fix) the magnetometer is the only heading reference and the filter
cannot observe what the calibration left: a hard iron b the calibration did not remove turns the heading by up to
asin(b/H) (H: the horizontal field), the same at every sample, so the filter's covariance (sensor noise, gyro)
shrinks while that error stays. The published 1σ therefore adds it as a "consider" term (Schmidt), independent
of the filter's own error: σ_pub² = σ_filter² + σ_cal².

σ_cal is the calibration's own predicted heading error (calibration/heading_trust.py: the field session's
heading and offset 1σ, else the fit's field residual over H at the fit site). With no calibration, or one that
does not say how good it is, the error is unknown: vehicle iron is commonly as strong as the horizontal field
itself (the simulator's default boat: 45 µT horizontal hard iron against ~20 µT; a battery, a motor or a steel
hull a few centimetres away does the same) and once b ≥ H every heading is possible, so no finite prior would be
honest. σ_cal is then π: the heading state becomes UNKNOWN and no heading goes to an autopilot — what ArduPilot
("Compass not calibrated": no arming) and PX4 (preflight "Compass Sensor 0 uncalibrated") do with an uncalibrated
compass.

The estimator library's default is 0 (no term): data handed to an estimator directly is taken as calibrated by
whoever hands it; the daemon always states its calibration's figure (NaN: none).
"""

from __future__ import annotations

import math

UNKNOWN_CALIBRATION_SIGMA_RAD = math.pi
"""The heading 1σ of a magnetometer of unknown calibration: the heading is unknown (module docstring)."""


def calibration_states_error(mag_calibration_sigma_rad: float) -> bool:
    """The calibration states the heading error it leaves (a finite 1σ ≥ 0); NaN: none, or its quality unknown.
    The circle check (field_circle.py) runs only then: with none, σ is π and a check could add nothing."""
    s = float(mag_calibration_sigma_rad)
    return math.isfinite(s) and s >= 0.0


def calibration_heading_variance_rad2(mag_calibration_sigma_rad: float) -> float:
    """The calibration's heading variance (rad²) to add to a magnetometer-held heading's: the 1σ given squared
    when it is finite and ≥ 0, else (NaN: no calibration, or its quality unknown) UNKNOWN_CALIBRATION_SIGMA_RAD².
    (The calibration's own figure is calibration/heading_trust.calibration_heading_sigma_rad.)"""
    s = float(mag_calibration_sigma_rad)
    return (s if calibration_states_error(s) else UNKNOWN_CALIBRATION_SIGMA_RAD) ** 2
