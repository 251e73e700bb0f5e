"""The `[magcal]` config section: how the field magnetometer calibration behaves (daemon.magcal). Apart from
the protocol handler, so loading the config does not import the field session."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any

from ahrsd.calibration.mag.swing import DEFAULT_MIN_SPEED_M_S


@dataclass(frozen=True)
class MagCalSettings:
    """Behaviour of the mag-cal protocol handler (the daemon's `[magcal]` config section)."""

    accept_broadcast: bool = False       # act on target_component 0 (MAVProxy `magcal`): also starts the autopilot's cal
    allow_armed: bool = False            # calibrate while the autopilot reports armed
    vehicle_type: str = "auto"           # auto | level | tumble
    fitness_mgauss: float = 16.0         # ArduPilot COMPASS_CAL_FIT default
    timeout_s: float = 300.0             # sample time from start to full coverage
    progress_rate_hz: float = 4.0        # MAG_CAL_PROGRESS while running
    report_rate_hz: float = 1.0          # MAG_CAL_REPORT while finished and not accepted/cancelled
    fixed_yaw_average_s: float = 1.0     # raw field averaged for MAV_CMD_FIXED_MAG_CAL_YAW
    # GNSS course for the heading offset: the fix's time of validity is its arrival minus this latency
    # (ArduPilot AP_GPS_UBLOX::get_lag: 0.12 s for u-blox M8/F9), used above this ground speed
    gnss_latency_s: float = 0.12
    course_min_speed_m_s: float = DEFAULT_MIN_SPEED_M_S
    # GLOBAL_POSITION_INT (the autopilot's fused velocity) when no GPS_RAW_INT arrives: only when the autopilot
    # does not fuse our heading (docs/gnss.md "The loop through the autopilot")
    course_from_global_position_int: bool = False


def settings_from_mapping(d: dict[str, Any] | None) -> MagCalSettings:
    """`[magcal]` TOML table -> MagCalSettings; raises ValueError naming the bad key."""
    d = dict(d or {})
    out: dict[str, Any] = {}
    fields = {f: type(v) for f, v in asdict(MagCalSettings()).items()}   # each key's type, by its default
    for key, value in d.items():
        if key not in fields:
            raise ValueError(f"unknown config key magcal.{key}: allowed keys are {', '.join(fields)}")
        want = fields[key]
        if want is bool and not isinstance(value, bool):
            raise ValueError(f"config key magcal.{key} = {value!r} is invalid: true or false")
        if want is float and (isinstance(value, bool) or not isinstance(value, (int, float))
                              or not (math.isfinite(value) and value > 0)):
            # inf would pass "> 0": an infinite progress rate makes the mag-cal ticker spin
            raise ValueError(f"config key magcal.{key} = {value!r} is invalid: a positive finite number")
        if key == "vehicle_type" and value not in ("auto", "level", "tumble"):
            raise ValueError(f"config key magcal.vehicle_type = {value!r} is invalid: one of 'auto', 'level', 'tumble'")
        out[key] = float(value) if want is float else value
    return replace(MagCalSettings(), **out)
