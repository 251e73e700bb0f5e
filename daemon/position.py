"""Where the vehicle is, for the World Magnetic Model: the one priority every user of a position follows
(the declination, daemon.declination; the field calibration's reference field, daemon.magcal).

Priority, first available wins:
1. the configured position (`[location] lat_deg/lon_deg/alt_m`): the operator said so;
2. the GNSS receiver of `[gnss] source` (its last accepted fix with a position);
3. the autopilot's position (GPS_RAW_INT / GLOBAL_POSITION_INT), when `[location] use_autopilot_position`;
4. the position remembered from the GNSS receiver or the autopilot (daemon.position_memory: kept in the state
   directory across restarts, up to a year old): the last real position is a better guess than none;
5. the simulator's site, when the sensor is the simulator.
The memory is fed where positions arrive, not where they are asked for: each GNSS fix and each autopilot GPS
message hands the live position (2., else 3.) to it (`note_live_position`; it saves by its own rule), also when
the configured position outranks it. `position()` only reads.
A position given with a request (MAV_CMD_FIXED_MAG_CAL_YAW's lat/lon) is used for that request only and is
not a source here. The manual declination (DECL_MANUAL/DECL_DEG) is a declination, not a position: it sits
above all of these in daemon.declination only.
"""

from __future__ import annotations

import datetime
from dataclasses import dataclass
from typing import Callable, Protocol

from ahrsd.core.wmm import EarthField, earth_field
from ahrsd.daemon.position_memory import PositionMemory
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
    source: str                          # "config", "gnss", "autopilot", "remembered", "simulator"
    date: datetime.date | None = None    # the WMM epoch to use (the simulator's site has its own)
    remembered: str = ""                 # a remembered position: its source and date ("gnss, 2026-12-04")
    age: str = ""                        # a remembered position: its age ("26 h old")

    def earth_field(self) -> EarthField:
        return earth_field(self.lat_deg, self.lon_deg, self.alt_m, self.date)

    def describe(self) -> str:
        """Where the position came from, for a person: "remembered (gnss, 2026-12-04, 1.2 days old)"."""
        return f"remembered ({self.remembered}, {self.age})" if self.source == "remembered" else self.source


class PositionResolver:
    """The position by the module's priority. `location` is the `[location]` config section; `gnss_position`
    returns the receiver's (lat, lon, alt) or None; `simulator` says whether the sensor is the simulator;
    `memory` keeps the last live position (None: nothing remembered, nothing kept)."""

    def __init__(self, location, *, gnss_position: Callable[[], tuple[float, float, float] | None],
                 autopilot: AutopilotPosition, simulator: bool, memory: PositionMemory | None = None):
        self.location = location
        self.gnss_position = gnss_position
        self.autopilot = autopilot
        self.simulator = simulator
        self.memory = memory

    def position(self) -> Position | None:
        """The position by the module's priority, None without one."""
        loc = self.location
        if loc.lat_deg is not None:
            return Position(loc.lat_deg, loc.lon_deg, loc.alt_m, "config")
        live = self._live_position()
        if live is not None:
            return live
        kept = None if self.memory is None else self.memory.usable()
        if kept is not None:
            now = self.memory.wall_clock()
            # a clock behind the saved date (no real-time clock, time not set yet): the saved date is the best
            # known lower bound of today for the WMM's secular variation
            date = kept.saved_date if kept.age_s(now) < 0 else None
            return Position(kept.lat_deg, kept.lon_deg, kept.alt_m, "remembered", date,
                            remembered=f"{kept.source}, {kept.saved_date.isoformat()}", age=kept.describe_age(now))
        if self.simulator:
            site = DEFAULT_SITE
            return Position(site.lat_deg, site.lon_deg, site.alt_m, "simulator", site.date)
        return None

    def note_live_position(self) -> None:
        """A GNSS fix or an autopilot position arrived: the live position goes to the memory, which saves it by
        its own rule (daemon.position_memory; nothing from a simulator or a replay)."""
        live = self._live_position()
        if live is not None and self.memory is not None:
            self.memory.note(live.lat_deg, live.lon_deg, live.alt_m, live.source)

    def _live_position(self) -> Position | None:
        """The GNSS receiver's position, else the autopilot's (when the config allows it), else None."""
        gnss = self.gnss_position()
        if gnss is not None:
            return Position(*gnss, "gnss")
        ap = self.autopilot
        if self.location.use_autopilot_position and ap.lat_deg is not None and ap.lon_deg is not None:
            return Position(ap.lat_deg, ap.lon_deg, ap.alt_m, "autopilot")
        return None

    def reference_field(self) -> EarthField | None:
        """The WMM field at the resolved position, None without one."""
        p = self.position()
        return None if p is None else p.earth_field()
