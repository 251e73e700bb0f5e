"""Where the vehicle is, for the World Magnetic Model: the one priority every user of a position follows
(the declination, daemon.declination; the field calibration's reference field, daemon.magcal).

Priority, first available wins:
1. the configured position (`[location] lat_deg/lon_deg/alt_m`): the operator said so;
2. the GNSS receiver of `[gnss] source` (its last accepted fix with a position);
3. the autopilot's position (GPS_RAW_INT / GLOBAL_POSITION_INT), when `[location] use_autopilot_position`;
4. the simulator's site, when the sensor is the simulator.
A position given with a request (MAV_CMD_FIXED_MAG_CAL_YAW's lat/lon) is used for that request only and is
not a source here. The manual declination (DECL_MANUAL/DECL_DEG) is a declination, not a position: it sits
above all of these in daemon.declination only.
"""

from __future__ import annotations

import datetime
from dataclasses import dataclass
from typing import Callable, Protocol

from ahrsd.core.wmm import EarthField, earth_field
from ahrsd.simulation import DEFAULT_SITE


class AutopilotPosition(Protocol):
    """What the resolver reads of daemon.autopilot.AutopilotState."""

    lat_deg: float | None
    lon_deg: float | None
    alt_m: float


@dataclass(frozen=True)
class Position:
    lat_deg: float
    lon_deg: float
    alt_m: float
    source: str                          # "config", "gnss", "autopilot", "simulator"
    date: datetime.date | None = None    # the WMM epoch to use (the simulator's site has its own)

    def earth_field(self) -> EarthField:
        return earth_field(self.lat_deg, self.lon_deg, self.alt_m, self.date)


class PositionResolver:
    """The position by the module's priority. `location` is the `[location]` config section; `gnss_position`
    returns the receiver's (lat, lon, alt) or None; `simulator` says whether the sensor is the simulator."""

    def __init__(self, location, *, gnss_position: Callable[[], tuple[float, float, float] | None],
                 autopilot: AutopilotPosition, simulator: bool):
        self.location = location
        self.gnss_position = gnss_position
        self.autopilot = autopilot
        self.simulator = simulator

    def position(self) -> Position | None:
        loc = self.location
        if loc.lat_deg is not None:
            return Position(loc.lat_deg, loc.lon_deg, loc.alt_m, "config")
        gnss = self.gnss_position()
        if gnss is not None:
            return Position(*gnss, "gnss")
        ap = self.autopilot
        if loc.use_autopilot_position and ap.lat_deg is not None and ap.lon_deg is not None:
            return Position(ap.lat_deg, ap.lon_deg, ap.alt_m, "autopilot")
        if self.simulator:
            site = DEFAULT_SITE
            return Position(site.lat_deg, site.lon_deg, site.alt_m, "simulator", site.date)
        return None

    def reference_field(self) -> EarthField | None:
        """The WMM field at the resolved position, None without one."""
        p = self.position()
        return None if p is None else p.earth_field()
