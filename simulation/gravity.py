"""Gravity and Earth rotation in the local NED frame at a place (the magnitude model is core/gravity.py)."""

from __future__ import annotations

import numpy as np

from ahrsd.core.gravity import EARTH_RADIUS_M, EARTH_RATE_RAD_S, normal_gravity_m_s2


def gravity_ned_m_s2(lat_deg, alt_m=0.0) -> np.ndarray:
    """Local gravity vector in NED (points down): [0, 0, g]."""
    return np.array([0.0, 0.0, normal_gravity_m_s2(lat_deg, alt_m)])


def earth_rate_ned_rad_s(lat_deg) -> np.ndarray:
    """Earth rotation rate expressed in NED at latitude `lat_deg`: ω_ie [cos L, 0, −sin L] (Groves 2nd ed. §5.4).

    (3,) for a scalar latitude, (n, 3) for an array of n latitudes."""
    lat = np.radians(np.asarray(lat_deg, dtype=float))
    w = EARTH_RATE_RAD_S * np.stack([np.cos(lat), np.zeros_like(lat), -np.sin(lat)], axis=-1)
    return w


def transport_rate_ned_rad_s(vel_ned_m_s, lat_deg, alt_m) -> np.ndarray:
    """Rotation rate of the NED frame over the spherical Earth, ω_en = [V_E, −V_N, −V_E tan L] / (R0 + h)
    (Groves 2nd ed. §5.4); vel (n, 3), lat/alt (n,) → (n, 3)."""
    v = np.asarray(vel_ned_m_s, dtype=float)
    r = EARTH_RADIUS_M + np.asarray(alt_m, dtype=float)
    tan_lat = np.tan(np.radians(np.asarray(lat_deg, dtype=float)))
    return np.stack([v[..., 1], -v[..., 0], -v[..., 1] * tan_lat], axis=-1) / r[..., None]
