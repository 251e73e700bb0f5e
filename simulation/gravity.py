"""Gravity and Earth rotation in the local NED frame at a place (the magnitude model is core/gravity.py)."""

from __future__ import annotations

import numpy as np

from ahrsd.core.gravity import normal_gravity_m_s2

EARTH_RATE_RAD_S = 7.292e-5         # Earth rotation rate (WGS-84 7.292115e-5 rad/s, rounded)


def gravity_ned_m_s2(lat_deg, alt_m=0.0) -> np.ndarray:
    """Local gravity vector in NED (points down): [0, 0, g]."""
    return np.array([0.0, 0.0, normal_gravity_m_s2(lat_deg, alt_m)])


def earth_rate_ned_rad_s(lat_deg) -> np.ndarray:
    """Earth rotation rate expressed in NED at latitude `lat_deg`: ω_ie [cos L, 0, −sin L]."""
    lat = np.radians(float(lat_deg))
    return EARTH_RATE_RAD_S * np.array([np.cos(lat), 0.0, -np.sin(lat)])
