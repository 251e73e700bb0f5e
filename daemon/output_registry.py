"""The MAVLink outputs ahrsd publishes: one entry per message, and everything about an output derives from it.

From `OUTPUTS` come the `[outputs]` config keys and their limits (daemon.config.OutputsConfig), the `SR_`
rate parameters (daemon.param_protocol), the streams of the scheduler (daemon.outputs.OutputSchedule, in
this order), and what SET_MESSAGE_INTERVAL / GET_MESSAGE_INTERVAL / REQUEST_MESSAGE accept
(daemon.builtin_commands). Adding an output is one `OutputSpec` here and one builder (a pure function in
daemon/messages.py plus the few lines below that feed it the service state).

The GNSS outputs (LOCAL_POSITION_NED, GLOBAL_POSITION_INT, default 0 Hz = off) are entries whose builders
read the aided estimator's navigation state (AttitudeEstimate.nav); each endpoint has its own OutputSchedule
built from the same entries (daemon.endpoint_outputs); `priority` orders outputs when a serial link must drop some.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Protocol

from ahrsd.core.estimate import HeadingState
from ahrsd.daemon import messages as msgs
from ahrsd.daemon.mavlink_io import mavlink

DEFAULT_MAX_RATE_HZ = 200.0
VISION_MAX_RATE_HZ = 50.0       # ArduPilot EKF3 extNavIntervalMin_ms = 20 ms (AP_NavEKF3_Measurements.cpp)
NAV_MAX_RATE_HZ = 50.0          # a display of the track needs a few Hz


class OutputContext(Protocol):
    """What the builders read besides the estimate and the sample (daemon.service provides it)."""

    @property
    def declination_rad(self) -> float: ...
    def time_boot_ms(self, now: float | None = None) -> int: ...
    def sample_time_monotonic(self, t_s: float) -> float: ...
    def heading_trusted(self, now: float) -> bool: ...
    def autopilot_yaw(self, est) -> tuple[float, int, float]: ...   # (yaw to send, reset_counter, its 1σ): daemon.heading_resets
    #   (reset_counter + 1 first when the estimator reset its yaw: EstimateFlags.YAW_RESET, daemon.heading_status)
    def autopilot_yaw_withheld(self, est) -> None: ...          # no yaw sent for est: daemon.heading_resets.withheld
    def sys_status_message(self, now: float): ...
    def local_origin(self): ...                                 # daemon.local_origin.LocalOrigin, None without GNSS


@dataclass(frozen=True)
class OutputSpec:
    """One published message.

    build(context: OutputContext, estimate, sample, now) -> message or None (None: nothing trustworthy to send now).
    needs_estimate: only built once the estimator has produced an estimate and samples are fresh.
    once_per_estimate: sent to an endpoint at most once for each estimate (its time stamp): a measurement the
    autopilot fuses must not arrive twice with the same time when no new sample came between two due times.
    priority: 0 = dropped last by a serial link that cannot keep up (daemon.serial_queue), higher numbers
    first: 0 the heading the autopilot fuses, 1 health, 2 attitude for displays, 3 raw sensor data.
    """

    message_id: int
    config_key: str          # [outputs] key, Hz
    param_name: str          # SR_ parameter, ≤ 16 characters
    default_hz: float
    max_rate_hz: float
    build: Callable
    needs_estimate: bool = True
    priority: int = 1
    once_per_estimate: bool = False


def _attitude(ctx, est, sample, now):
    return msgs.attitude(est, ctx.time_boot_ms(now), est.heading_true_rad)


def _attitude_quaternion(ctx, est, sample, now):
    return msgs.attitude_quaternion(est, ctx.time_boot_ms(now), ctx.declination_rad)


def _vision_position_estimate(ctx, est, sample, now):
    if not ctx.heading_trusted(now) or est.heading_state == HeadingState.UNKNOWN:
        ctx.autopilot_yaw_withheld(est)   # a running slew turns with the vehicle meanwhile
        return None   # never feed the autopilot a heading it must not trust, nor one nobody knows
    usec = int(ctx.sample_time_monotonic(est.t_s) * 1e6)
    yaw, reset_counter, yaw_sigma_rad = ctx.autopilot_yaw(est)
    return msgs.vision_position_estimate(est, usec, yaw, reset_counter, yaw_sigma_rad)


def _highres_imu(ctx, est, sample, now):
    return None if sample is None else msgs.highres_imu(sample, int(ctx.sample_time_monotonic(sample.t_s) * 1e6))


def _scaled_imu(ctx, est, sample, now):
    return None if sample is None else msgs.scaled_imu(sample, ctx.time_boot_ms(now))


def _sys_status(ctx, est, sample, now):
    return ctx.sys_status_message(now)


def _local_position_ned(ctx, est, sample, now):
    nav, origin = est.nav, ctx.local_origin()
    if nav is None or origin is None:
        return None     # no navigation state: an unaided estimator, or no fix yet
    return msgs.local_position_ned(ctx.time_boot_ms(now), origin.ned_m(nav.lat_deg, nav.lon_deg, nav.alt_m),
                                   nav.vel_ned_m_s)


def _global_position_int(ctx, est, sample, now):
    nav, origin = est.nav, ctx.local_origin()
    if nav is None or origin is None:
        return None
    # alt: the ellipsoid height (ahrsd has no geoid model; docs/gnss.md "Altitude"); relative to the origin
    relative_alt = -origin.ned_m(nav.lat_deg, nav.lon_deg, nav.alt_m)[2]
    return msgs.global_position_int(ctx.time_boot_ms(now), nav.lat_deg, nav.lon_deg, nav.alt_m, relative_alt,
                                    nav.vel_ned_m_s, est.heading_true_rad)


OUTPUTS: tuple[OutputSpec, ...] = (
    OutputSpec(mavlink.MAVLINK_MSG_ID_ATTITUDE, "attitude_hz", "SR_ATTITUDE", 50.0, DEFAULT_MAX_RATE_HZ,
               _attitude, priority=2),
    OutputSpec(mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, "attitude_quaternion_hz", "SR_ATT_QUAT", 10.0,
               DEFAULT_MAX_RATE_HZ, _attitude_quaternion, priority=2),
    # ArduPilot needs > 3.3 Hz, PX4 > 5 Hz
    OutputSpec(mavlink.MAVLINK_MSG_ID_VISION_POSITION_ESTIMATE, "vision_position_estimate_hz", "SR_VISION_POS",
               30.0, VISION_MAX_RATE_HZ, _vision_position_estimate, priority=0, once_per_estimate=True),
    OutputSpec(mavlink.MAVLINK_MSG_ID_HIGHRES_IMU, "highres_imu_hz", "SR_HIGHRES_IMU", 10.0, DEFAULT_MAX_RATE_HZ,
               _highres_imu, priority=3),
    OutputSpec(mavlink.MAVLINK_MSG_ID_SCALED_IMU, "scaled_imu_hz", "SR_SCALED_IMU", 0.0, DEFAULT_MAX_RATE_HZ,
               _scaled_imu, priority=3),
    OutputSpec(mavlink.MAVLINK_MSG_ID_SYS_STATUS, "sys_status_hz", "SR_SYS_STATUS", 1.0, DEFAULT_MAX_RATE_HZ,
               _sys_status, needs_estimate=False, priority=1),
    # the aided estimator's navigation state, for a display (off by default; not meant for the autopilot)
    OutputSpec(mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, "local_position_ned_hz", "SR_LOCAL_POS", 0.0,
               NAV_MAX_RATE_HZ, _local_position_ned, priority=3),
    OutputSpec(mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, "global_position_int_hz", "SR_GLOBAL_POS", 0.0,
               NAV_MAX_RATE_HZ, _global_position_int, priority=3),
)

BY_MESSAGE_ID: dict[int, OutputSpec] = {o.message_id: o for o in OUTPUTS}
BY_CONFIG_KEY: dict[str, OutputSpec] = {o.config_key: o for o in OUTPUTS}
BY_PARAM_NAME: dict[str, OutputSpec] = {o.param_name: o for o in OUTPUTS}
