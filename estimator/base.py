"""The estimator interface shared by every attitude estimator (design §5)."""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ahrsd.drivers.sample import ImuSample


class EstimateFlags(enum.IntFlag):
    NONE = 0
    INITIALISING = 1 << 0     # not yet converged: do not publish a heading the autopilot trusts
    MAG_REJECTED = 1 << 1     # magnetometer update gated out on this step (disturbance)
    ACCEL_REJECTED = 1 << 2   # accelerometer update gated out (linear acceleration)
    AT_REST = 1 << 3          # rest detected: gyro bias being learned
    MAG_UNAVAILABLE = 1 << 4  # no usable magnetometer for a while: heading from gyro only, uncertainty growing
    LARGE_DT = 1 << 5         # a time gap was seen; the filter propagated over it or re-initialised
    REINITIALISED = 1 << 6


@dataclass(frozen=True, slots=True)
class AttitudeEstimate:
    """Attitude of the body (FRD) in NED at time t_s.

    q_wxyz: Hamilton, scalar first, rotates body vectors into NED (design §4).
    roll/pitch/yaw_rad: ZYX Euler; yaw is magnetic (relative to magnetic north).
    heading_true_rad = yaw + declination, wrapped to [0, 2π).
    sigma_rpy_rad: 1σ uncertainty of roll, pitch, yaw.
    """

    t_s: float
    q_wxyz: np.ndarray
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    heading_mag_rad: float
    heading_true_rad: float
    rate_body_rad_s: np.ndarray      # bias-corrected angular rate
    gyro_bias_rad_s: np.ndarray
    sigma_rpy_rad: np.ndarray
    flags: EstimateFlags = EstimateFlags.NONE


class Estimator(Protocol):
    name: str

    def update(self, sample: ImuSample) -> AttitudeEstimate: ...

    def reset(self) -> None: ...

    def set_declination(self, declination_rad: float) -> None: ...

    def relearn_field_reference(self) -> None:
        """The magnetometer calibration changed: re-learn whatever reference of the field the estimator
        keeps (magnitude, dip) from the next samples, keeping attitude and gyro bias (no heading step)."""
