"""How far a magnetometer calibration change moves the estimator's heading: the tilt-compensated heading of the
current sample's field under the new calibration, minus the estimator's (magnetic) heading.

The estimator's heading was made with the old calibration (and the gyro bias it learned from it), so this is the
heading error it may have from the moment the new one is in force — what the new calibration will move it by.
The estimator widens its yaw variance to it (relearn_field_reference), which keeps its σ honest and its Kalman
gain right while it converges to the new heading."""

from __future__ import annotations

import math

import numpy as np

from ahrsd.core.angles import tilt_compensated_heading_rad, wrap_pi


def calibration_heading_change_rad(old_cal, new_cal, raw_mag_ut, mounting, roll_rad: float, pitch_rad: float,
                                   yaw_rad: float) -> float:
    """The magnetic heading (rad) of the latest field under `new_cal` minus the estimator's yaw, wrapped to
    (−π, π].

    raw_mag_ut: the latest field as the source gave it, sensor frame (Pipeline.last_raw_sample); mounting: the
    sensor → body rotation (3×3) or None; roll/pitch/yaw: the estimator's, yaw from magnetic north, rad. 0 when
    the magnetometer model did not change from `old_cal`'s (a gyro or accelerometer calibration moves no heading
    reference), NaN when it cannot be told (no sample, no field)."""
    if old_cal.mag == new_cal.mag:
        return 0.0
    if raw_mag_ut is None or not all(math.isfinite(a) for a in (roll_rad, pitch_rad, yaw_rad)):
        return math.nan
    field = new_cal.mag.apply(np.asarray(raw_mag_ut, dtype=np.float64))
    if mounting is not None:
        field = np.asarray(mounting, dtype=np.float64) @ field
    if not np.all(np.isfinite(field)) or np.linalg.norm(field) <= 0.0:
        return math.nan
    heading = float(tilt_compensated_heading_rad(field, roll_rad, pitch_rad)[0])
    return float(wrap_pi(heading - yaw_rad))
