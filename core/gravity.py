"""Normal gravity at a place: the 1980 International Gravity Formula (GRS80 series) with a spherical
height correction.

g(L, 0) = 9.780327 (1 + 0.0053024 sin²L − 0.0000058 sin²2L)  m/s²
g(L, h) = g(L, 0) · (R0 / (R0 + h))²,  R0 = 6 378 137 m (WGS-84 equatorial radius)

(the series form of GRS80 normal gravity, H. Moritz, "Geodetic Reference System 1980", J. Geodesy 74, 2000;
the 1967 formula has 9.780318 and 0.0000059). "Gravity" here is mass
attraction plus the centripetal term of the Earth's rotation, i.e. what a level accelerometer at rest reads
(with the sign flipped: specific force points up).
"""

from __future__ import annotations

import numpy as np

EARTH_RADIUS_M = 6_378_137.0        # WGS-84 equatorial radius, used as a spherical Earth radius
G_EQUATOR_M_S2 = 9.780327           # 1980 International Gravity Formula (GRS80 series)
G_SIN2_COEFF = 0.0053024
G_SIN2_2L_COEFF = 0.0000058
EARTH_RATE_RAD_S = 7.292e-5        # Earth rotation rate (WGS-84 7.292115e-5 rad/s, rounded): 15.04 °/h


def normal_gravity_m_s2(lat_deg, alt_m=0.0):
    """Magnitude of local gravity (m/s²) at geodetic latitude `lat_deg` and height `alt_m` (m) above the ellipsoid.

    Vectorised over numpy arrays; returns a float for scalar input.
    """
    lat = np.radians(np.asarray(lat_deg, dtype=float))
    h = np.asarray(alt_m, dtype=float)
    g0 = G_EQUATOR_M_S2 * (1.0 + G_SIN2_COEFF * np.sin(lat) ** 2 - G_SIN2_2L_COEFF * np.sin(2.0 * lat) ** 2)
    g = g0 * (EARTH_RADIUS_M / (EARTH_RADIUS_M + h)) ** 2
    return float(g) if np.ndim(g) == 0 else g
