"""The estimate every estimator produces (CONTRIBUTING.md): attitude of the body in NED, with flags and 1σ."""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

from ahrsd.core.slot_init import slot_init


class EstimateFlags(enum.IntFlag):
    NONE = 0
    INITIALISING = 1 << 0     # not yet converged: do not publish a heading the autopilot trusts
    MAG_REJECTED = 1 << 1     # magnetometer update gated out on this step (disturbance)
    ACCEL_REJECTED = 1 << 2   # accelerometer update gated out (linear acceleration)
    AT_REST = 1 << 3          # rest detected: gyro bias being learned
    MAG_UNAVAILABLE = 1 << 4  # no usable magnetometer for a while: heading from gyro only, uncertainty growing
    LARGE_DT = 1 << 5         # a time gap was seen; the filter propagated over it or re-initialised
    REINITIALISED = 1 << 6
    GNSS_AIDED = 1 << 7       # ins: GNSS velocity/position fused recently (horizon and heading aided)
    GNSS_OUTAGE = 1 << 8      # ins: GNSS was fusing and stopped: dead-reckoning, then unaided behaviour
    GNSS_REJECTED = 1 << 9    # ins: a GNSS measurement was gated out on this step (glitch)
    YAW_RESET = 1 << 10       # ins: its filter yaw was reset on this step (to the GNSS yaw); the published yaw slews


class HeadingState(enum.IntEnum):
    """Where the published heading comes from, and whether it can be trusted (docs/estimator.md "Heading state").

    UNKNOWN: no heading reference is good enough to publish one (initialising, magnetometer rejected and no
    GNSS yaw yet): consumers must not use the heading; the daemon withholds VISION_POSITION_ESTIMATE.
    MAGNETOMETER: the magnetometer is the heading reference and is consistent (with GNSS, when there is one).
    GNSS_ONLY: the magnetometer is rejected (disagrees with the GNSS yaw, or disturbed) and the heading is held
    by the GNSS velocity (the aided filter, reset to the Gaussian-sum yaw when needed).
    LEARNING: GNSS holds the heading while the magnetometer's remaining error (iron) is being learned; the
    magnetometer re-enters once its learned correction is consistent.
    """

    UNKNOWN = 0
    MAGNETOMETER = 1
    GNSS_ONLY = 2
    LEARNING = 3


@slot_init       # built once per estimate: the cheaper __init__
@dataclass(frozen=True, slots=True)
class HeadingIntegrity:
    """The heading checks of an aided estimator at one instant (angles true, rad; NaN where not known)."""

    gsf_yaw_rad: float                   # the magnetometer-free GNSS yaw (Gaussian-sum estimator), true north
    gsf_sigma_rad: float                 # its 1σ (includes the spread between hypotheses)
    gsf_valid: bool                      # enough horizontal acceleration seen, σ below the validity limit
    mag_disagreement_rad: float          # magnetometer heading − GNSS yaw, wrapped to ±π
    iron_offset_ut: np.ndarray           # (3,) learned hard iron (body frame) on top of the calibration, µT
    iron_sigma_ut: np.ndarray            # (3,) its 1σ
    mag_step_rad: float = float("nan")   # the magnetometer is rejected now for a step of its heading the gyro did not
                                         # see (estimator/mag_step.py): the step's size (NaN: not rejected for a step)
    lever_arm_wrong: bool = False        # the GNSS velocities fit another antenna place than the one told, and no
                                         # adopted arm has been shown right yet (LeverArmFit.heading_bent)
                                         # (estimator/lever_arm_fit.py): the heading is unknown until the arm is set


@slot_init       # built once per estimate: the cheaper __init__
@dataclass(frozen=True, slots=True)
class AttitudeEstimate:
    """Attitude of the body (FRD) in NED at time t_s.

    q_wxyz: Hamilton, scalar first, rotates body vectors into NED.
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
    nav: "NavState | None" = None    # position/velocity, only from an aided estimator
    heading_state: HeadingState = HeadingState.MAGNETOMETER
    integrity: "HeadingIntegrity | None" = None  # only from an aided estimator


@slot_init       # built once per estimate: the cheaper __init__
@dataclass(frozen=True, slots=True)
class NavState:
    """Position and velocity of the IMU from an aided estimator (ins). NED velocity m/s, WGS-84 geodetic."""

    vel_ned_m_s: np.ndarray          # (3,)
    lat_deg: float
    lon_deg: float
    alt_m: float                     # height above the WGS-84 ellipsoid
    sigma_vel_m_s: np.ndarray        # (3,) 1σ north/east/down
    sigma_pos_m: np.ndarray          # (3,) 1σ north/east/down
    accel_bias_m_s2: np.ndarray      # (3,) estimated accelerometer bias, body frame
