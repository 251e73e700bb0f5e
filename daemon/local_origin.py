"""A local NED frame for LOCAL_POSITION_NED: the first navigation position is its origin.

Positions are mapped to north/east/down metres on the tangent plane of the origin with the WGS-84 radii of
curvature there (meridian R_N = a(1−e²)/(1−e² sin²φ)^1.5, prime vertical R_E = a/√(1−e² sin²φ); Groves,
"Principles of GNSS, Inertial, and Multisensor Integrated Navigation Systems", 2nd ed., eqs. 2.105–2.106):
metre-accurate within a few kilometres, which is what a display of the track needs.
"""

from __future__ import annotations

import math

WGS84_A_M = 6378137.0                 # semi-major axis
WGS84_E2 = 6.69437999014e-3           # first eccentricity squared


class LocalOrigin:
    """`ned_m(lat, lon, alt)` relative to the first position it was given (which becomes the origin)."""

    def __init__(self):
        self.origin: tuple[float, float, float] | None = None
        self._r_n_m = self._r_e_cos_m = 0.0

    def ned_m(self, lat_deg: float, lon_deg: float, alt_m: float) -> tuple[float, float, float]:
        if self.origin is None:
            self.origin = (lat_deg, lon_deg, alt_m)
            s2 = math.sin(math.radians(lat_deg)) ** 2
            w = 1.0 - WGS84_E2 * s2
            self._r_n_m = WGS84_A_M * (1.0 - WGS84_E2) / w ** 1.5 + alt_m
            self._r_e_cos_m = (WGS84_A_M / math.sqrt(w) + alt_m) * math.cos(math.radians(lat_deg))
        lat0, lon0, alt0 = self.origin
        d_lon = math.remainder(lon_deg - lon0, 360.0)
        return (math.radians(lat_deg - lat0) * self._r_n_m, math.radians(d_lon) * self._r_e_cos_m, alt0 - alt_m)
