"""Declination (true heading = magnetic heading + declination), by priority: DECL_MANUAL/DECL_DEG, the
configured position, the GNSS receiver's position, the autopilot's position, the simulator's site; a step larger than
DECLINATION_RESET_STEP_RAD is a heading reset the autopilot is told about."""

from __future__ import annotations

import logging
import math
import time

from ahrsd.core.wmm import earth_field
from ahrsd.simulation import DEFAULT_SITE

log = logging.getLogger(__name__)

DECLINATION_RESET_STEP_RAD = math.radians(0.5)   # a heading step this large increments reset_counter


class DeclinationResolver:
    """Service part: `_resolve_declination` (start, every 10 s, on a position or DECL_* change)."""

    def _resolve_declination(self, initial: bool = False) -> None:
        """Declination by priority: DECL_MANUAL/DECL_DEG, configured position, GNSS position ([gnss] source),
        autopilot position, sim site."""
        self._last_decl_update = time.monotonic()
        loc = self.config.location
        decl, source = None, ""
        if self.params.get("DECL_MANUAL") >= 0.5:
            decl, source = math.radians(self.params.get("DECL_DEG")), "manual"
        elif loc.lat_deg is not None:
            decl = earth_field(loc.lat_deg, loc.lon_deg, loc.alt_m).declination_rad
            source = f"WMM at {loc.lat_deg:.4f},{loc.lon_deg:.4f} (config)"
        elif self.gnss is not None and self.gnss.position is not None:
            lat, lon, alt = self.gnss.position
            decl = earth_field(lat, lon, alt).declination_rad
            source = "WMM at the GNSS position"   # no coordinates: they change while moving (logged on change)
        elif loc.use_autopilot_position and self.autopilot.lat_deg is not None:
            ap = self.autopilot
            decl = earth_field(ap.lat_deg, ap.lon_deg, ap.alt_m).declination_rad
            source = f"WMM at {ap.lat_deg:.4f},{ap.lon_deg:.4f} (autopilot)"
        elif self.config.sensor.source == "sim":
            site = DEFAULT_SITE
            decl = earth_field(site.lat_deg, site.lon_deg, site.alt_m, site.date).declination_rad
            source = "WMM at the simulator's site"
        if decl is None:
            if initial:
                log.warning("no position and no declination configured: true heading = magnetic heading until "
                            "the autopilot reports a position")
            decl, source = 0.0, "none (no position yet)"
        self._set_declination(decl, source)

    def on_gnss_position(self) -> None:
        """The first GNSS fix: it outranks the autopilot's position and the simulator's site."""
        if not (self.declination_source == "manual" or self.declination_source.endswith("(config)")):
            self._resolve_declination()

    def _set_declination(self, decl: float, source: str) -> None:
        step = abs(math.remainder(decl - self.declination_rad, 2 * math.pi))
        if source != self.declination_source:
            log.info("declination %.2f° from %s", math.degrees(decl), source)
        self.declination_rad, self.declination_source = decl, source
        if self.pipeline is not None and step > 1e-9:
            self.pipeline.estimator.set_declination(decl)
            if step > DECLINATION_RESET_STEP_RAD:
                self.signal_heading_reset()

