"""The autopilot backend: GNSS from MAVLink GPS_RAW_INT (msg id 24) and GLOBAL_POSITION_INT (msg id 33).

Pure converters from pymavlink messages (anything with the fields as attributes), a small selector that
prefers the raw receiver, and `MavlinkGnssBackend`, the GnssBackend (backend.py) fed every message from the
autopilot through `offer(msg, t_s)`. Field units and "unknown" sentinels follow the MAVLink common.xml definitions:

- GPS_RAW_INT: fix_type (GPS_FIX_TYPE), lat/lon degE7, alt mm (MSL), eph/epv DOP×100 (UINT16_MAX unknown),
  vel cm/s ground speed and cog cdeg (UINT16_MAX unknown), satellites_visible (UINT8_MAX unknown); MAVLink 2
  extensions alt_ellipsoid mm, h_acc/v_acc mm, vel_acc mm/s (0 when not filled in: a MAVLink 1 packet
  or an autopilot that does not know them; UINT32_MAX treated the same). No vertical velocity.
- GLOBAL_POSITION_INT: the autopilot's *fused* estimate: lat/lon degE7, alt mm (MSL), vx/vy/vz cm/s NED.
  No fix type and no accuracies. It depends on the autopilot's heading, which may be ours: see docs/gnss.md
  ("The loop through the autopilot") before enabling it.
"""

from __future__ import annotations

import logging
import math

from .backend import GnssBackend, GnssHealth, GnssLinkState
from ahrsd.core.gnss import GnssFix, GnssFixType, make_fix

log = logging.getLogger(__name__)

UINT8_MAX = 0xFF
UINT16_MAX = 0xFFFF
UINT32_MAX = 0xFFFFFFFF
RAW_TIMEOUT_S = 2.0


def _or_nan(value: int, scale: float, *unknown: int) -> float:
    return math.nan if value is None or value in unknown else value * scale


def fix_from_gps_raw_int(msg, t_s: float, source: str = "mavlink:GPS_RAW_INT") -> GnssFix:
    """GPS_RAW_INT -> GnssFix valid at `t_s` (the caller's arrival time minus the link/receiver latency).

    Velocity: north = vel·cos(cog), east = vel·sin(cog), down NaN. Unknown vel or cog -> NaN velocity (a
    known vel of 0 with an unknown course is a stationary receiver: velocity 0). Altitude: alt_ellipsoid when
    present (non-zero), else the MSL alt with extra["alt_msl"] = True.
    """
    try:
        fix_type = GnssFixType(int(msg.fix_type))
    except ValueError:            # a newer GPS_FIX_TYPE (7 static, 8 PPP): a 3D fix as far as we are concerned
        fix_type = GnssFixType.FIX_3D if int(msg.fix_type) > GnssFixType.RTK_FIXED else GnssFixType.NO_FIX
    speed = _or_nan(msg.vel, 0.01, UINT16_MAX)
    course = _or_nan(msg.cog, 0.01, UINT16_MAX)
    if speed == 0.0 and math.isnan(course):
        course = 0.0
    c = math.radians(course)
    vel = (speed * math.cos(c), speed * math.sin(c), math.nan)
    alt_ellipsoid = getattr(msg, "alt_ellipsoid", 0) or 0
    alt = alt_ellipsoid / 1000.0 if alt_ellipsoid != 0 else msg.alt / 1000.0
    extra = {"alt_msl": alt_ellipsoid == 0, "receiver_time_s": msg.time_usec * 1e-6,
             "vdop": _or_nan(msg.epv, 0.01, UINT16_MAX)}
    sats = int(msg.satellites_visible)
    return make_fix(t_s, msg.lat * 1e-7, msg.lon * 1e-7, alt, vel,
                    h_acc_m=_or_nan(getattr(msg, "h_acc", 0), 1e-3, 0, UINT32_MAX),
                    v_acc_m=_or_nan(getattr(msg, "v_acc", 0), 1e-3, 0, UINT32_MAX),
                    s_acc_m_s=_or_nan(getattr(msg, "vel_acc", 0), 1e-3, 0, UINT32_MAX),
                    fix_type=fix_type, num_sats=-1 if sats == UINT8_MAX else sats,
                    hdop=_or_nan(msg.eph, 0.01, UINT16_MAX), source=source, extra=extra)


def fix_from_global_position_int(msg, t_s: float, source: str = "mavlink:GLOBAL_POSITION_INT") -> GnssFix:
    """GLOBAL_POSITION_INT -> GnssFix valid at `t_s`: vx/vy/vz cm/s NED, MSL altitude, no accuracies.

    It has no fix type: lat = lon = 0 (what autopilots send before they have a position) is NO_FIX, anything
    else FIX_3D.
    """
    no_position = msg.lat == 0 and msg.lon == 0
    return make_fix(t_s, msg.lat * 1e-7, msg.lon * 1e-7, msg.alt / 1000.0,
                    (msg.vx * 0.01, msg.vy * 0.01, msg.vz * 0.01),
                    fix_type=GnssFixType.NO_FIX if no_position else GnssFixType.FIX_3D, source=source,
                    extra={"alt_msl": True, "receiver_time_s": msg.time_boot_ms * 1e-3, "fused": True})


class MavlinkGnssSelector:
    """Pick the autopilot's GNSS messages: GPS_RAW_INT always; GLOBAL_POSITION_INT only if `use_fused` and
    no GPS_RAW_INT with a fix arrived within `raw_timeout_s` (by the caller's clock `t_s`).

    ArduPilot sends GPS_RAW_INT at its stream rate (SRx_EXT_STAT) whether or not the receiver has a new fix,
    stamped with the time of the last fix (AP_GPS::send_mavlink_gps_raw: last_fix_time_ms): a message
    whose time_usec equals the previous one is the same fix again and is dropped (counted), not a new
    measurement.

    `handle(msg, t_s) -> GnssFix | None`; `counters` says how many of each were used or skipped.
    """

    def __init__(self, use_fused: bool = False, raw_timeout_s: float = RAW_TIMEOUT_S):
        self.use_fused = use_fused
        self.raw_timeout_s = raw_timeout_s
        self._last_raw_fix_t_s = -math.inf
        self._last_raw_time_usec = None
        self.counters = {"gps_raw_int": 0, "gps_raw_int_repeated": 0, "global_position_int": 0,
                         "global_position_int_skipped": 0}

    def handle(self, msg, t_s: float) -> GnssFix | None:
        kind = msg.get_type() if hasattr(msg, "get_type") else type(msg).__name__
        if kind == "GPS_RAW_INT":
            if msg.time_usec == self._last_raw_time_usec:
                self.counters["gps_raw_int_repeated"] += 1
                return None
            self._last_raw_time_usec = msg.time_usec
            fix = fix_from_gps_raw_int(msg, t_s)
            self.counters["gps_raw_int"] += 1
            if fix.fix_type >= GnssFixType.FIX_2D:
                self._last_raw_fix_t_s = t_s
            return fix
        if kind == "GLOBAL_POSITION_INT":
            if self.use_fused and t_s - self._last_raw_fix_t_s > self.raw_timeout_s:
                self.counters["global_position_int"] += 1
                return fix_from_global_position_int(msg, t_s)
            self.counters["global_position_int_skipped"] += 1
        return None


class MavlinkGnssBackend(GnssBackend):
    """The autopilot's receiver as a GnssBackend: `offer(msg, t_s)` takes every message from the autopilot
    (received at `t_s` on the samples' clock), the selector converts GPS_RAW_INT (and the opt-in
    GLOBAL_POSITION_INT fallback) into fixes valid at t_s − latency_s, `read()` hands them over once.

    A message the converter cannot use (a hostile or malformed field) is counted in `unusable` and logged,
    never raised."""

    def __init__(self, use_fused: bool = False, latency_s: float = 0.0):
        self.selector = MavlinkGnssSelector(use_fused=use_fused)
        self.latency_s = float(latency_s)
        self.description = "autopilot GPS_RAW_INT" + (" (GLOBAL_POSITION_INT fallback)" if use_fused else "")
        self.unusable = 0
        self._ready: list[GnssFix] = []

    def offer(self, msg, t_s: float) -> None:
        try:
            fix = self.selector.handle(msg, t_s - self.latency_s)
        except Exception as exc:  # noqa: BLE001 - a hostile message must not reach past the edge
            self.unusable += 1
            log.warning("GNSS: %s not usable: %s", type(msg).__name__, exc)
            return
        if fix is not None:
            self._ready.append(fix)

    def read(self) -> list[GnssFix]:
        fixes, self._ready = self._ready, []
        return fixes

    def health(self) -> GnssHealth:
        c = self.selector.counters
        used = c["gps_raw_int"] + c["global_position_int"]
        if used == 0:
            return GnssHealth(GnssLinkState.WAITING, "no GPS_RAW_INT from the autopilot yet")
        return GnssHealth(GnssLinkState.OK, f"{used} messages from the autopilot, {self.unusable} unusable")

    def stats(self) -> dict[str, dict]:
        return {"mavlink": {**self.selector.counters, "unusable": self.unusable}}
