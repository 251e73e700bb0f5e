"""Earth magnetic field from the World Magnetic Model 2025 (pygeomag), in ahrsd's units.

One place for the WMM lookup: the estimator (declination for true heading), the calibrations (reference
field magnitude and inclination) and the simulator (truth field) all call `earth_field`.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import functools
import math
from dataclasses import dataclass

import numpy as np

WMM_COEFFICIENTS = "wmm/WMM_2025.COF"  # shipped inside pygeomag; valid 2025.0-2030.0


@dataclass(frozen=True, slots=True)
class EarthField:
    """The main field at one place and date. NED components in µT; angles in radians."""

    north_ut: float
    east_ut: float
    down_ut: float
    declination_rad: float    # east of true north positive
    inclination_rad: float    # dip, positive down

    @property
    def ned_ut(self) -> np.ndarray:
        return np.array([self.north_ut, self.east_ut, self.down_ut])

    @property
    def horizontal_ut(self) -> float:
        return math.hypot(self.north_ut, self.east_ut)

    @property
    def total_ut(self) -> float:
        return math.sqrt(self.north_ut**2 + self.east_ut**2 + self.down_ut**2)


@functools.lru_cache(maxsize=1)
def _geomag():
    from pygeomag import GeoMag

    return GeoMag(coefficients_file=WMM_COEFFICIENTS)


_fixed_date: _dt.date | None = None    # fixed_date(): the date a lookup without one uses instead of today


@contextlib.contextmanager
def fixed_date(date: _dt.date):
    """Within it, a lookup without a date evaluates the field on `date`, not today: the field moves by a few nT
    from one day to the next (the secular variation), and a tool whose output must be reproducible
    (tools/estimate_digest.py, a digest of every estimate) must not change at midnight."""
    global _fixed_date
    before, _fixed_date = _fixed_date, date
    try:
        yield
    finally:
        _fixed_date = before


def decimal_year(date: _dt.date | None = None) -> float:
    date = date or _fixed_date or _dt.date.today()
    start = _dt.date(date.year, 1, 1)
    days = (_dt.date(date.year + 1, 1, 1) - start).days
    return date.year + (date - start).days / days


@functools.lru_cache(maxsize=256)
def _lookup(lat_deg: float, lon_deg: float, alt_m: float, year: float) -> EarthField:
    r = _geomag().calculate(glat=lat_deg, glon=lon_deg, alt=alt_m / 1000.0, time=year)
    return EarthField(
        north_ut=r.x / 1000.0,  # pygeomag reports nT
        east_ut=r.y / 1000.0,
        down_ut=r.z / 1000.0,
        declination_rad=math.radians(r.d),
        inclination_rad=math.radians(r.i),
    )


def earth_field(lat_deg: float, lon_deg: float, alt_m: float = 0.0, date: _dt.date | None = None) -> EarthField:
    """WMM2025 field at (lat, lon, altitude above the ellipsoid in metres) on `date` (default today)."""
    if not (-90.0 <= lat_deg <= 90.0) or not (-180.0 <= lon_deg <= 360.0):
        raise ValueError(f"position out of range: lat {lat_deg}, lon {lon_deg}")
    return _lookup(round(lat_deg, 4), round(lon_deg, 4), round(alt_m, 0), round(decimal_year(date), 3))
