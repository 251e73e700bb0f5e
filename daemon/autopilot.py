"""What ahrsd learns from the autopilot: system id, armed flag, position (for the WMM declination), and
course/speed over ground (for the field magnetometer calibration's swing fit)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from ahrsd.daemon.mavlink_io import mavlink

UINT16_MAX = 0xFFFF
GPS_FIX_3D = 3


@dataclass
class AutopilotState:
    system_id: int | None = None        # sysid of the first autopilot heartbeat seen
    component_id: int | None = None
    armed: bool = False
    last_heartbeat: float | None = None
    lat_deg: float | None = None
    lon_deg: float | None = None
    alt_m: float = 0.0
    position_time: float | None = None
    course_rad: float | None = None     # course over ground, true north, [0, 2π)
    ground_speed_m_s: float | None = None
    velocity_time: float | None = None

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
            self.armed = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            self.last_heartbeat = now
        return latched

    def on_global_position_int(self, msg, now: float) -> None:
        if msg.lat == 0 and msg.lon == 0:
            return   # "no position" as autopilots send it before a fix
        self.lat_deg, self.lon_deg, self.alt_m = msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3
        self.position_time = now
        vn, ve = msg.vx * 0.01, msg.vy * 0.01      # cm/s → m/s, NED
        self.ground_speed_m_s = math.hypot(vn, ve)
        self.course_rad = math.atan2(ve, vn) % (2 * math.pi)
        self.velocity_time = now

    def on_gps_raw_int(self, msg, now: float) -> None:
        if msg.fix_type < GPS_FIX_3D:
            return
        self.lat_deg, self.lon_deg, self.alt_m = msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3
        self.position_time = now
        if msg.vel != UINT16_MAX:
            self.ground_speed_m_s = msg.vel * 0.01
        if msg.cog != UINT16_MAX:
            self.course_rad = math.radians(msg.cog * 0.01) % (2 * math.pi)
        self.velocity_time = now
