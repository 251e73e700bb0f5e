"""Normal gravity at a place: the NED-frame local gravity model of seed 004 (eq. 18).

g(L, 0) = 9.780327 (1 + 0.0053024 sin²L − 0.0000058 sin²2L)  m/s²     # seed 004 §7.5, eq. 18
g(L, h) = g(L, 0) · (R0 / (R0 + h))²,  R0 = 6 378 137 m               # seed 004 §7.5 [R], §11

"Local gravity" here is mass attraction plus the centripetal term of the Earth's rotation (seed 004 §7.5), i.e.
what a level accelerometer at rest reads (with the sign flipped: specific force points up).
"""

from __future__ import annotations

import numpy as np

EARTH_RADIUS_M = 6_378_137.0        # seed 004 §11 (spherical Earth radius, WGS-84 equatorial)
EARTH_RATE_RAD_S = 7.292e-5         # seed 004 §7.2, eq. 15
G_EQUATOR_M_S2 = 9.780327           # seed 004 eq. 18
G_SIN2_COEFF = 0.0053024            # seed 004 eq. 18
G_SIN2_2L_COEFF = 0.0000058         # seed 004 eq. 18


def normal_gravity_m_s2(lat_deg, alt_m=0.0):
    """Magnitude of local gravity (m/s²) at geodetic latitude `lat_deg` and height `alt_m` (m) above the ellipsoid.

    Vectorised over numpy arrays; returns a float for scalar input.
    """
    lat = np.radians(np.asarray(lat_deg, dtype=float))
    h = np.asarray(alt_m, dtype=float)
    g0 = G_EQUATOR_M_S2 * (1.0 + G_SIN2_COEFF * np.sin(lat) ** 2 - G_SIN2_2L_COEFF * np.sin(2.0 * lat) ** 2)
    g = g0 * (EARTH_RADIUS_M / (EARTH_RADIUS_M + h)) ** 2
    return float(g) if np.ndim(g) == 0 else g


def gravity_ned_m_s2(lat_deg, alt_m=0.0) -> np.ndarray:
    """Local gravity vector in NED (points down): [0, 0, g]."""
    return np.array([0.0, 0.0, normal_gravity_m_s2(lat_deg, alt_m)])


def earth_rate_ned_rad_s(lat_deg) -> np.ndarray:
    """Earth rotation rate expressed in NED at latitude `lat_deg`: ω_ie [cos L, 0, −sin L] (seed 004 eq. 15).

    (3,) for a scalar latitude, (n, 3) for an array of n latitudes."""
    lat = np.radians(np.asarray(lat_deg, dtype=float))
    w = EARTH_RATE_RAD_S * np.stack([np.cos(lat), np.zeros_like(lat), -np.sin(lat)], axis=-1)
    return w


def transport_rate_ned_rad_s(vel_ned_m_s, lat_deg, alt_m) -> np.ndarray:
    """Rotation rate of the NED frame over the spherical Earth, ω_en = [V_E, −V_N, −V_E tan L] / (R0 + h)
    (seed 004 eq. 16); vel (n, 3), lat/alt (n,) → (n, 3)."""
    v = np.asarray(vel_ned_m_s, dtype=float)
    r = EARTH_RADIUS_M + np.asarray(alt_m, dtype=float)
    tan_lat = np.tan(np.radians(np.asarray(lat_deg, dtype=float)))
    return np.stack([v[..., 1], -v[..., 0], -v[..., 1] * tan_lat], axis=-1) / r[..., None]
