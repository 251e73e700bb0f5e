"""What ahrsd learns from the autopilot: system id, armed flag, position (for the WMM declination), and
course/speed over ground (for the field magnetometer calibration's swing fit).

A position or course that cannot be true (latitude beyond ±90°, an INT32_MAX "unknown" sentinel, an altitude
outside the WMM's validity, a fix type or course outside its enum/range) is refused and counted
(`rejected_positions`, `rejected_courses`, one rate-limited warning): it would otherwise step the declination —
hence the true heading sent to the autopilot — or make the WMM lookup raise."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Callable

from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.rate_limit import TokenBucket

log = logging.getLogger(__name__)

UINT16_MAX = 0xFFFF
GPS_FIX_3D = 3
GPS_FIX_TYPE_MAX = max(mavlink.enums["GPS_FIX_TYPE"]) - 1       # the last entry is ENUM_END
LAT_E7_MAX, LON_E7_MAX = 90 * 10**7, 180 * 10**7
COG_CDEG_MAX = 35999                                            # GPS_RAW_INT.cog: 0..359.99°, UINT16_MAX unknown
# WMM2025 validity: 1 km below to 850 km above the ellipsoid (NOAA/BGS WMM2025 technical report, §1)
WMM_ALT_MIN_M, WMM_ALT_MAX_M = -1000.0, 850_000.0


def position_problem_e7(lat_e7: int, lon_e7: int, alt_mm: int) -> str | None:
    """None for a position the WMM can be looked up at, else why not (degE7 / mm as MAVLink sends them)."""
    if not (-LAT_E7_MAX <= lat_e7 <= LAT_E7_MAX and -LON_E7_MAX <= lon_e7 <= LON_E7_MAX):
        return f"position {lat_e7 * 1e-7:.7g}, {lon_e7 * 1e-7:.7g} deg out of range"
    if not WMM_ALT_MIN_M <= alt_mm * 1e-3 <= WMM_ALT_MAX_M:
        return f"altitude {alt_mm * 1e-3:.6g} m outside the WMM's range"
    return None


@dataclass
class AutopilotState:
    system_id: int | None = None        # sysid of the first autopilot heartbeat seen
    component_id: int | None = None
    autopilot_kind: int | None = None   # HEARTBEAT.autopilot (MAV_AUTOPILOT: 3 ArduPilot, 12 PX4)
    armed: bool = False
    last_heartbeat: float | None = None
    lat_deg: float | None = None
    lon_deg: float | None = None
    alt_m: float = 0.0
    position_time: float | None = None
    course_rad: float | None = None     # course over ground, true north, [0, 2π)
    ground_speed_m_s: float | None = None
    velocity_time: float | None = None
    rejected_positions: int = 0         # GLOBAL_POSITION_INT / GPS_RAW_INT refused (see the module docstring)
    rejected_courses: int = 0
    _warn_budget: TokenBucket = field(default_factory=lambda: TokenBucket(rate_per_s=0.1, burst=3), repr=False)
    _gnss_listeners: list = field(default_factory=list, repr=False)

    def add_gnss_listener(self, fn: Callable[[object], None]) -> None:
        """`fn(msg)` after every GPS_RAW_INT / GLOBAL_POSITION_INT from the autopilot has been taken in
        (accepted or refused here: the listener judges the message for its own use). A listener that raises
        is logged; the input handling carries on."""
        self._gnss_listeners.append(fn)

    def _tell_gnss_listeners(self, msg) -> None:
        for fn in self._gnss_listeners:
            try:
                fn(msg)
            except Exception:  # noqa: BLE001 - a bad GNSS message must not stop the service's input handling
                log.exception("GNSS listener: %s not usable", msg.get_type())

    @staticmethod
    def is_autopilot_heartbeat(msg) -> bool:
        return msg.autopilot != mavlink.MAV_AUTOPILOT_INVALID and msg.type not in (
            mavlink.MAV_TYPE_GCS, mavlink.MAV_TYPE_GIMBAL, mavlink.MAV_TYPE_ADSB, mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
            mavlink.MAV_TYPE_IMU)

    def from_this_autopilot(self, msg) -> bool:
        return self.system_id is not None and msg.get_srcSystem() == self.system_id and (
            msg.get_srcComponent() == self.component_id)

    def on_heartbeat(self, msg, now: float) -> bool:
        """Update from an autopilot HEARTBEAT; True when this latched the autopilot's ids."""
        latched = False
        if self.system_id is None:
            self.system_id, self.component_id = msg.get_srcSystem(), msg.get_srcComponent()
            latched = True
        if self.from_this_autopilot(msg):
            self.autopilot_kind = msg.autopilot
            self.armed = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            self.last_heartbeat = now
        return latched

    def _refuse(self, what: str, reason: str, now: float) -> None:
        if self._warn_budget.take(now):
            log.warning("%s from the autopilot refused: %s", what, reason)

    def on_global_position_int(self, msg, now: float) -> None:
        self._take_global_position_int(msg, now)
        self._tell_gnss_listeners(msg)

    def on_gps_raw_int(self, msg, now: float) -> None:
        self._take_gps_raw_int(msg, now)
        self._tell_gnss_listeners(msg)

    def _take_position_e7(self, what: str, msg, problem: str | None, now: float) -> bool:
        """Take the message's lat, lon (degE7) and alt (mm) as the position, unless `problem` says why it cannot
        be true: then refuse it (counted, warned) and return False."""
        if problem:
            self.rejected_positions += 1
            self._refuse(what, problem, now)
            return False
        self.lat_deg, self.lon_deg, self.alt_m = msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3
        self.position_time = now
        return True

    def _take_global_position_int(self, msg, now: float) -> None:
        if msg.lat == 0 and msg.lon == 0:
            return   # "no position" as autopilots send it before a fix
        if not self._take_position_e7("GLOBAL_POSITION_INT", msg, position_problem_e7(msg.lat, msg.lon, msg.alt), now):
            return
        vn, ve = msg.vx * 0.01, msg.vy * 0.01      # cm/s → m/s, NED
        self.ground_speed_m_s = math.hypot(vn, ve)
        self.course_rad = math.atan2(ve, vn) % (2 * math.pi)
        self.velocity_time = now

    def _take_gps_raw_int(self, msg, now: float) -> None:
        if msg.fix_type < GPS_FIX_3D:
            return
        problem = (f"fix type {msg.fix_type} unknown" if msg.fix_type > GPS_FIX_TYPE_MAX
                   else position_problem_e7(msg.lat, msg.lon, msg.alt))
        if not self._take_position_e7("GPS_RAW_INT", msg, problem, now):
            return
        if msg.vel != UINT16_MAX:
            self.ground_speed_m_s = msg.vel * 0.01
        if COG_CDEG_MAX < msg.cog < UINT16_MAX:
            self.rejected_courses += 1
            self._refuse("GPS_RAW_INT", f"course {msg.cog * 0.01:g} deg out of range", now)
        elif msg.cog != UINT16_MAX:
            self.course_rad = math.radians(msg.cog * 0.01) % (2 * math.pi)
        self.velocity_time = now
