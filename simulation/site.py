"""Where and when the simulated vehicle is: the place fixes gravity (core.gravity) and the WMM2025 field."""

from __future__ import annotations

import datetime as _dt
import numbers
from dataclasses import dataclass

import numpy as np

from ahrsd.core.wmm import EarthField, earth_field
from ahrsd.core.gravity import normal_gravity_m_s2


@dataclass(frozen=True, slots=True)
class Site:
    """A place and date: geodetic latitude/longitude in degrees, height above the ellipsoid in metres."""

    lat_deg: float
    lon_deg: float
    alt_m: float
    date: _dt.date

    def __post_init__(self):
        for name, lo, hi in (("lat_deg", -90.0, 90.0), ("lon_deg", -180.0, 360.0), ("alt_m", -1000.0, 50_000.0)):
            v = getattr(self, name)
            if not (isinstance(v, numbers.Real) and np.isfinite(v) and lo <= v <= hi):
                raise ValueError(f"Site.{name} must be a number in [{lo:g}, {hi:g}], got {v!r}")
        if not isinstance(self.date, _dt.date):
            raise ValueError(f"Site.date must be a datetime.date, got {self.date!r}")

    @classmethod
    def parse(cls, text: str) -> "Site":
        """A site from "LAT,LON[,ALT_M[,YYYY-MM-DD]]" (degrees, metres), e.g. "47.37,8.54,420,2026-06-01"; missing
        height 0 m, missing date DEFAULT_SITE's. For command lines and benchmarks that need another place."""
        parts = [p.strip() for p in str(text).split(",")]
        if not 2 <= len(parts) <= 4:
            raise ValueError(f"site must be LAT,LON[,ALT_M[,YYYY-MM-DD]], got {text!r}")
        try:
            lat, lon = float(parts[0]), float(parts[1])
            alt = float(parts[2]) if len(parts) > 2 and parts[2] else 0.0
            date = _dt.date.fromisoformat(parts[3]) if len(parts) > 3 else DEFAULT_SITE.date
        except ValueError as exc:
            raise ValueError(f"site must be LAT,LON[,ALT_M[,YYYY-MM-DD]], got {text!r}: {exc}") from None
        return cls(lat, lon, alt, date)

    def earth_field(self) -> EarthField:
        """WMM2025 main field here (the only WMM lookup is `ahrsd.core.wmm.earth_field`)."""
        return earth_field(self.lat_deg, self.lon_deg, self.alt_m, self.date)

    @property
    def gravity_m_s2(self) -> float:
        """Local normal gravity magnitude (1980 International Gravity Formula × (R0/(R0+h))², core.gravity)."""
        return normal_gravity_m_s2(self.lat_deg, self.alt_m)

    @property
    def gravity_ned_m_s2(self) -> np.ndarray:
        return np.array([0.0, 0.0, self.gravity_m_s2])


# Shahrood, Iran: where the ADIS16405 AHRS thesis (Shahrood University of Technology) built and tested its AHRS;
# the AUV tests of Nourmohammadi & Sabet (J. of Control 16(3), 2022) were at a site with a similar field.
# Date fixed (inside WMM2025's validity) so that simulated data are the same on every run. The field WMM2025
# gives here is in docs/simulation.md.
DEFAULT_SITE = Site(lat_deg=36.42, lon_deg=54.98, alt_m=1345.0, date=_dt.date(2026, 1, 1))
