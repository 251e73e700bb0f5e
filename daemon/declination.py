"""Declination (true heading = magnetic heading + declination): DECL_MANUAL/DECL_DEG, else the WMM at the
position of daemon.position's priority (configured, GNSS receiver, autopilot, remembered, simulator site). A
step larger than DECLINATION_RESET_STEP_RAD is a heading reset the autopilot is told about."""

from __future__ import annotations

import logging
import math
import time
from typing import Callable, Protocol

from ahrsd.daemon.position import PositionResolver

log = logging.getLogger(__name__)

DECLINATION_RESET_STEP_RAD = math.radians(0.5)   # a heading step this large increments reset_counter
UPDATE_PERIOD_S = 10.0                           # re-resolved this often (a moving vehicle, a late fix)


class ParamReader(Protocol):
    def get(self, name: str) -> float: ...


def _label(position) -> str:
    if position.source == "gnss":
        return "WMM at the GNSS position"   # no coordinates: they change while moving (logged on change)
    if position.source == "simulator":
        return "WMM at the simulator's site"
    if position.source == "remembered":     # no age: the label stays the same while the age grows
        return f"WMM at {position.lat_deg:.4f},{position.lon_deg:.4f} (remembered from {position.remembered})"
    return f"WMM at {position.lat_deg:.4f},{position.lon_deg:.4f} ({position.source})"


class Declination:
    """Owns the declination in force (`rad`, `source`). `resolve()` at start, every UPDATE_PERIOD_S
    (`tick`), on a position or DECL_* change; the estimator gets each change through `set_estimator`
    (bound once the estimator exists) and a step beyond DECLINATION_RESET_STEP_RAD calls `signal_reset`."""

    def __init__(self, params: ParamReader, positions: PositionResolver, *, signal_reset: Callable[[], None],
                 clock: Callable[[], float] = time.monotonic):
        self.params = params
        self.positions = positions
        self.signal_reset = signal_reset
        self.clock = clock
        self.rad = 0.0
        self.source = "none"
        self.set_estimator: Callable[[float], None] | None = None
        self._last_update = -math.inf

    def resolve(self, initial: bool = False) -> None:
        self._last_update = self.clock()
        decl, source, age = None, "", ""
        if self.params.get("DECL_MANUAL") >= 0.5:
            decl, source = math.radians(self.params.get("DECL_DEG")), "manual"
        else:
            position = self.positions.position()
            if position is not None:
                decl, source, age = position.earth_field().declination_rad, _label(position), position.age
        if decl is None:
            if initial:
                log.warning("no position and no declination configured: true heading = magnetic heading until "
                            "the autopilot reports a position")
            decl, source = 0.0, "none (no position yet)"
        self._set(decl, source, age)

    @property
    def waiting_for_position(self) -> bool:
        return self.source.startswith("none")

    def on_gnss_position(self) -> None:
        """The first GNSS fix: it outranks the autopilot's, the remembered position and the simulator's site."""
        if not (self.source == "manual" or self.source.endswith("(config)")):
            self.resolve()

    def tick(self, now: float) -> None:
        if now - self._last_update > UPDATE_PERIOD_S:
            self.resolve()

    def _set(self, decl: float, source: str, age: str = "") -> None:
        step = abs(math.remainder(decl - self.rad, 2 * math.pi))
        if source != self.source:
            log.info("declination %.2f° from %s%s", math.degrees(decl), source, f", {age}" if age else "")
        self.rad, self.source = decl, source
        if self.set_estimator is not None and step > 1e-9:
            self.set_estimator(decl)
            if step > DECLINATION_RESET_STEP_RAD:
                self.signal_reset()
