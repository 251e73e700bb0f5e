"""A yaw slewed towards the estimator's (`YawSlew`): what an output sends while a heading change is moved in at a
bounded rate — its step and its 1σ. Two outputs build on it: ins's published heading, which absorbs the filter's
corrections (a yaw reset, fast GNSS updates) into an offset and slews it out (estimator/published_heading.py), and
the daemon's slew of a calibration change or a restart to the autopilot (daemon/heading_slew.py). Each keeps its
own published yaw (an offset from the filter's yaw, or the heading sent) and separates the vehicle's own rotation,
which is never slowed, from what is slewed; the step and the σ are this module's.

σ: the slewed yaw is off the estimator's by the offset d still to come, a known error, and the estimator's own
error e is on top of it: |d + e| ≤ |d| + |e| ≤ 3·(σ + |d|/3) whenever |e| ≤ 3σ. So with σ_sent = σ + |d|/3 the
slewed yaw is beyond its 3σ no more often than the estimator's is, and no smaller σ has that guarantee for every e
within 3σ; more would slow the autopilot to no purpose. Counting d as a 1σ error (√(σ² + d²)) claims 3·|d|, and
the autopilots weigh our variance: ArduPilot EKF3 fuses our yaw with R = max(angErr, VISO_YAW_M_NSE, 5°)²
(AP_VisualOdom_MAV.cpp handle_pose_estimate, AP_NavEKF3_Measurements.cpp writeExtNavData, AP_NavEKF3_MagFusion.cpp
fuseEulerYaw; angErr = sqrt(roll + pitch + yaw variance) since ArduPilot PR #32084, GCS_Common.cpp, before it the
cube root of their squares). With R that large EKF3's yaw hardly follows the slew while d is large, and lags
beyond its gate, 3·sqrt(P + R), once d and R are small again. With d/3 the gate is at least 3σ + |d| while d
exceeds 15° − 3σ, and R is EKF3's 5° floor below that. PX4 EKF2 floors our variance at EKF2_EVA_NOISE
(ev_yaw_control.cpp), so only a large d changes anything there.

Rate: the slew rates (ins's 2 °/s, the daemon's heading_slew_deg_s and restart_slew_deg_s) were chosen for R at
EKF3's floor. While σ_sent is above it EKF3's yaw follows more slowly even with the honest σ, and a faster slew
leaves it beyond its gate (docs/daemon.md "Restarts"), so the rate is held to LARGE_OFFSET_MAX_RATE_RAD_S then:
at that rate the fake EKF3s of tests/support/fake_autopilot_yaw.py (the sources' R, floors and gate) fuse every
VPE of any change with that σ (bench/slew_variance.py)."""

from __future__ import annotations

import math

EKF3_YAW_FLOOR_RAD = math.radians(5.0)
"""ArduPilot EKF3's floor on the external-yaw observation 1σ (AP_NavEKF3_Measurements.cpp writeExtNavData)."""
LARGE_OFFSET_MAX_RATE_RAD_S = math.radians(2.0)
"""The slew rate while the σ sent is above EKF3_YAW_FLOOR_RAD (module docstring)."""


class YawSlew:
    """One rule for every slewed yaw: the published yaw moves towards the estimator's at no more than `rate_rad_s`
    (slower while the σ sent is above EKF3's floor: `slew_step`), all the way once it is within that step or within
    `arrive_within_rad`; the σ sent with it is sigma_rad (σ + |offset|/3)."""

    __slots__ = ("rate_rad_s", "arrive_within_rad")

    def __init__(self, rate_rad_s: float, arrive_within_rad: float = 0.0):
        self.rate_rad_s = rate_rad_s
        self.arrive_within_rad = arrive_within_rad

    def step(self, offset_rad: float, sigma_rad: float, dt_s: float) -> tuple[float, bool]:
        """(move, arrived) over dt_s for a published yaw `offset_rad` off the estimator's (published − estimator's,
        within ±π), the estimator's yaw 1σ being `sigma_rad`: the move to add to the published yaw, −offset_rad
        when it arrives, else the step against the offset."""
        return slew_step(self.rate_rad_s, self.arrive_within_rad, offset_rad, sigma_rad, dt_s)

    @staticmethod
    def sigma_rad(sigma_rad: float, offset_rad: float) -> float:
        """The 1σ of the published yaw `offset_rad` off the estimator's, whose 1σ is `sigma_rad`: σ + |offset|/3
        (module docstring)."""
        return sigma_rad + abs(offset_rad) / 3.0


def slew_step(rate_rad_s: float, arrive_within_rad: float, offset_rad: float, sigma_rad: float,
              dt_s: float) -> tuple[float, bool]:
    """YawSlew.step of a slew at `rate_rad_s` that arrives within `arrive_within_rad`. Plain arithmetic that numba
    compiles as it is (slewed_yaw_kernel.py: ins's published heading steps it at every sample, inside its compiled
    run of a block's samples too), so it calls no Python function: the rate (no more than
    LARGE_OFFSET_MAX_RATE_RAD_S while the σ sent for the offset, YawSlew.sigma_rad's σ + |offset|/3, which EKF3's
    floor was compared with, is above EKF3's floor) is worked out here."""
    size = abs(offset_rad)
    # within the step of the least rate the slew can go at, it arrives at any σ: the rate is not worked out (the
    # routine case: ins's published heading asks at every sample)
    if size <= min(rate_rad_s, LARGE_OFFSET_MAX_RATE_RAD_S) * dt_s:
        return -offset_rad, True
    rate = rate_rad_s
    if rate_rad_s > LARGE_OFFSET_MAX_RATE_RAD_S and sigma_rad + size / 3.0 > EKF3_YAW_FLOOR_RAD:
        rate = LARGE_OFFSET_MAX_RATE_RAD_S
    allowed = rate * dt_s
    if size <= allowed or size <= arrive_within_rad:
        return -offset_rad, True
    return -math.copysign(allowed, offset_rad), False
