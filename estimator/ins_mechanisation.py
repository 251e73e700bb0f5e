"""NED strapdown mechanisation of the `ins` estimator: gravity, Earth rate, transport rate, position and
velocity rates (the local-navigation-frame equations of Groves, "Principles of GNSS, Inertial, and Multisensor
Integrated Navigation Systems", 2nd ed., 2013, §5.4), as scalar functions compiled with numba.

They are called from the filter kernel (`ins_core.py`) and are plain callables from Python too (the tests
check them against the equations and worked values).

Earth model. Gravity is the 1980 International Gravity Formula (GRS80 series, core/gravity.py) with a spherical
(R0/(R0+h))² height factor. The radii are those
of the WGS-84 ellipsoid (meridian R_N and prime-vertical R_E, Groves 2nd ed. eqs. 2.105–2.106) instead of the
sphere of radius R0: GNSS receivers report WGS-84 geodetic positions, and on the sphere a north displacement would
be mis-scaled by up to 0.7 % (15 m over 2 km at mid-latitudes). With r_n = r_e = R every function is exactly
the spherical form (R_N = R_E = R0).
"""

from __future__ import annotations

import math

from numba import njit

# the constants of the one gravity model (core/gravity.py); this module is its scalar, compiled twin for the
# per-sample path (numba freezes module-level floats at compile time)
from ahrsd.core.gravity import EARTH_RADIUS_M as SPHERE_RADIUS_M
from ahrsd.core.gravity import EARTH_RATE_RAD_S, G_EQUATOR_M_S2, G_SIN2_2L_COEFF, G_SIN2_COEFF

WGS84_A_M = 6_378_137.0              # WGS-84 semi-major axis
WGS84_E2 = 6.69437999014e-3          # WGS-84 first eccentricity squared


@njit(cache=True)
def normal_gravity_m_s2(lat_rad, h_m):
    """Local gravity magnitude g(L, h) = 9.780327 (1 + 0.0053024 sin²L − 0.0000058 sin²2L) (R0/(R0+h))²,
    m/s² (1980 International Gravity Formula, GRS80 series): mass attraction plus the centripetal term of the
    Earth's rotation."""
    s = math.sin(lat_rad)
    s2 = math.sin(2.0 * lat_rad)
    g0 = G_EQUATOR_M_S2 * (1.0 + G_SIN2_COEFF * s * s - G_SIN2_2L_COEFF * s2 * s2)
    k = SPHERE_RADIUS_M / (SPHERE_RADIUS_M + h_m)
    return g0 * k * k


@njit(cache=True)
def earth_rate_ned(lat_rad):
    """ω_ie^n = ω_ie [cos L, 0, −sin L], rad/s (Groves 2nd ed. eq. 2.123)."""
    return EARTH_RATE_RAD_S * math.cos(lat_rad), 0.0, -EARTH_RATE_RAD_S * math.sin(lat_rad)


@njit(cache=True)
def radii_of_curvature_m(lat_rad):
    """(R_N, R_E): WGS-84 meridian and prime-vertical radii of curvature at latitude L, m."""
    s = math.sin(lat_rad)
    d = 1.0 - WGS84_E2 * s * s
    r_e = WGS84_A_M / math.sqrt(d)
    return r_e * (1.0 - WGS84_E2) / d, r_e


@njit(cache=True)
def transport_rate_ned(lat_rad, h_m, vn, ve, r_n, r_e):
    """ω_en^n = [V_E/(R_E+h), −V_N/(R_N+h), −V_E tan L/(R_E+h)], rad/s (Groves 2nd ed. eq. 5.44; R_N = R_E = R
    is the spherical Earth)."""
    re = r_e + h_m
    return ve / re, -vn / (r_n + h_m), -ve * math.tan(lat_rad) / re


@njit(cache=True)
def position_rates(lat_rad, h_m, vn, ve, vd, r_n, r_e):
    """(L̇, λ̇, ḣ) = (V_N/(R_N+h), V_E/((R_E+h) cos L), −V_D) in rad/s, rad/s, m/s (the rates Groves 2nd ed.
    eq. 5.56 integrates)."""
    return vn / (r_n + h_m), ve / ((r_e + h_m) * math.cos(lat_rad)), -vd


@njit(cache=True)
def velocity_rate_ned(fn, fe, fd, vn, ve, vd, lat_rad, h_m, r_n, r_e, earth_rotates):
    """V̇ = f^n − (2 ω_ie^n + ω_en^n) × V + g_l^n, m/s² (Groves 2nd ed. eq. 5.54 in continuous form),
    f^n = C_b^n f^b. earth_rotates False drops the Earth rate and transport rate (a flat, non-rotating Earth)."""
    g = normal_gravity_m_s2(lat_rad, h_m)
    if not earth_rotates:
        return fn, fe, fd + g
    wn, we, wd = earth_rate_ned(lat_rad)
    tn, te, td = transport_rate_ned(lat_rad, h_m, vn, ve, r_n, r_e)
    an = 2.0 * wn + tn
    ae = 2.0 * we + te
    ad = 2.0 * wd + td
    # a × V
    cn = ae * vd - ad * ve
    ce = ad * vn - an * vd
    cd = an * ve - ae * vn
    return fn - cn, fe - ce, fd - cd + g


__all__ = [
    "EARTH_RATE_RAD_S", "SPHERE_RADIUS_M", "WGS84_A_M", "WGS84_E2", "normal_gravity_m_s2", "earth_rate_ned",
    "radii_of_curvature_m", "transport_rate_ned", "position_rates", "velocity_rate_ned",
]
