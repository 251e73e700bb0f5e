"""Strapdown inertial navigation in the NED frame (local-navigation-frame mechanisation:
Groves, "Principles of GNSS, Inertial, and Multisensor Integrated Navigation Systems", 2nd ed., §5.4;
Titterton & Weston, "Strapdown Inertial Navigation Technology", 2nd ed., ch. 3).

Integrates gyro and accelerometer samples into attitude, NED velocity and geodetic position on a spherical Earth
(R0 = 6 378 137 m; normal gravity from the 1980 International Gravity Formula, core.gravity).
It serves to check the simulator (the truth specific force and rate must integrate back into the truth
trajectory) and as a reference for dead reckoning.

Per step k → k+1, second order in Δt:
  1. ω̃ = ω̄ − C_n^b (ω_ie + ω_en)        body rate relative to NED; ω̄ = trapezoid of the gyro samples
  2. C_b^n ← C_b^n exp(ω̃ Δt)           (exact for a constant rate over the step)
  3. f^n = C_b^n f^b
  4. V̇ = f^n − (2ω_ie + ω_en) × V + g   Heun predictor–corrector
  5. L̇ = V_N/(R+h), λ̇ = V_E/((R+h) cos L), ḣ = −V_D   trapezoid
Attitude maths: unit quaternions in plain floats here (mechanise_ned, per step) and scipy's Rotation
(mechanise_inertial); the simulation never uses the estimator's rotation code.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.integrate import cumulative_trapezoid
from scipy.spatial.transform import Rotation

from ahrsd.core.gravity import EARTH_RADIUS_M, normal_gravity_m_s2
from ahrsd.core.gravity import EARTH_RATE_RAD_S


@dataclass(frozen=True, eq=False)
class NavSolution:
    """Per-sample navigation output: t_s (n,), q_wxyz (n,4) body→NED, v_ned_m_s (n,3), lat_deg, lon_deg, h_m (n,)."""

    t_s: np.ndarray
    q_wxyz: np.ndarray
    v_ned_m_s: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    h_m: np.ndarray


def _rates_ned(lat, h, v, earth_rate: bool):
    """(ω_ie^n, ω_en^n) in rad/s at latitude `lat` (rad), height h, NED velocity v, as 3-tuples:
    ω_ie^n = ω_ie [cos L, 0, −sin L], ω_en^n = [V_E, −V_N, −V_E tan L]/(R0 + h) (Groves 2nd ed. §5.4)."""
    if not earth_rate:
        return (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    r = EARTH_RADIUS_M + h
    return ((EARTH_RATE_RAD_S * math.cos(lat), 0.0, -EARTH_RATE_RAD_S * math.sin(lat)),
            (v[1] / r, -v[0] / r, -v[1] * math.tan(lat) / r))


# The attitude as a unit quaternion (w, x, y, z), body → NED, in plain floats: one step is a dozen small
# products, which Python floats do faster than numpy or scipy's Rotation objects (Hamilton convention, as
# scipy's; this module uses neither the estimator's rotation code nor its conventions' helpers).

def _quat_product(a, b):
    """a ⊗ b: the rotation b followed by a (scipy's `Rotation(a) * Rotation(b)`)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw)


def _quat_of_rotvec(rx, ry, rz):
    """exp of the rotation vector (rad): the rotation by its norm about its direction."""
    angle = math.sqrt(rx * rx + ry * ry + rz * rz)
    half = 0.5 * angle
    # sin(θ/2)/θ, by its series where θ is too small to divide by (as scipy's from_rotvec does)
    scale = 0.5 - angle * angle / 48.0 if angle < 1e-3 else math.sin(half) / angle
    return math.cos(half), rx * scale, ry * scale, rz * scale


def _normalised(q):
    w, x, y, z = q
    n = math.sqrt(w * w + x * x + y * y + z * z)
    return w / n, x / n, y / n, z / n


def _rotate(q, v, inverse: bool = False):
    """C v with C the rotation q (body → NED); Cᵀ v with `inverse`."""
    w, x, y, z = q
    if inverse:
        x, y, z = -x, -y, -z
    vx, vy, vz = v
    # v + 2w (u × v) + 2 u × (u × v), u = (x, y, z)
    tx = 2.0 * (y * vz - z * vy)
    ty = 2.0 * (z * vx - x * vz)
    tz = 2.0 * (x * vy - y * vx)
    return (vx + w * tx + (y * tz - z * ty), vy + w * ty + (z * tx - x * tz), vz + w * tz + (x * ty - y * tx))


def mechanise_ned(t_s, gyro_rad_s, accel_m_s2, q0_wxyz, v0_ned_m_s, lat0_deg: float, lon0_deg: float,
                  h0_m: float, *, earth_rate: bool = True,
                  gravity_m_s2: Callable[[float, float], float] | None = None) -> NavSolution:
    """Integrate samples (gyro ω_ib^b, accel f^b, body frame) from the initial state at t_s[0].

    earth_rate: True for the rotating-Earth mechanisation (Earth rate, transport rate, Coriolis);
    False for a flat, non-rotating Earth (what `open_stream(..., earth_rate=False)` simulates).
    gravity_m_s2(lat_deg, h_m): local gravity magnitude; default the 1980 International Gravity Formula
      with the (R0/(R0+h))² height factor (core.gravity).
    """
    t = np.asarray(t_s, dtype=float)
    w_b = np.asarray(gyro_rad_s, dtype=float)
    f_b = np.asarray(accel_m_s2, dtype=float)
    n = len(t)
    if w_b.shape != (n, 3) or f_b.shape != (n, 3) or n < 1:
        raise ValueError("t_s (n,), gyro_rad_s (n,3) and accel_m_s2 (n,3) must have the same length n ≥ 1")
    g_of = gravity_m_s2 or normal_gravity_m_s2
    q = _normalised(tuple(float(c) for c in np.asarray(q0_wxyz, dtype=float)))
    v = tuple(float(c) for c in np.asarray(v0_ned_m_s, dtype=float))
    lat, lon, h = math.radians(lat0_deg), math.radians(lon0_deg), float(h0_m)
    t_list, w_list, f_list = t.tolist(), w_b.tolist(), f_b.tolist()

    quats = np.empty((n, 4))
    vel = np.empty((n, 3))
    pos = np.empty((n, 3))
    a_k = _v_dot(q, f_list[0], v, lat, h, earth_rate, g_of)
    for k in range(n):
        quats[k] = q
        vel[k] = v
        pos[k] = (lat, lon, h)
        if k == n - 1:
            break
        q, v, (lat, lon, h), a_k = _heun_step(t_list[k + 1] - t_list[k], q, v, lat, lon, h, a_k, w_list[k],
                                             w_list[k + 1], f_list[k + 1], earth_rate, g_of)
    quats *= np.where(quats[:, :1] < 0, -1.0, 1.0)
    return NavSolution(t, quats, vel, np.degrees(pos[:, 0]), np.degrees(pos[:, 1]), pos[:, 2])


def _v_dot(q, f_body, v, lat, h, earth_rate: bool, g_of):
    """Step 4's V̇ = C_b^n f^b − (2ω_ie + ω_en) × V + g at attitude q, NED velocity v, latitude lat (rad), h."""
    w_ie, w_en = _rates_ned(lat, h, v, earth_rate)
    wx, wy, wz = 2.0 * w_ie[0] + w_en[0], 2.0 * w_ie[1] + w_en[1], 2.0 * w_ie[2] + w_en[2]
    fx, fy, fz = _rotate(q, f_body)
    g = float(g_of(math.degrees(lat), h))
    return (fx - (wy * v[2] - wz * v[1]), fy - (wz * v[0] - wx * v[2]), fz - (wx * v[1] - wy * v[0]) + g)


def _pos_dot(v, lat, h):
    """Step 5's (L̇, λ̇, ḣ) for NED velocity v at latitude lat (rad) and height h."""
    r = EARTH_RADIUS_M + h
    return v[0] / r, v[1] / (r * math.cos(lat)), -v[2]


def _heun_step(dt, q, v, lat, lon, h, a_k, w_k, w_next, f_next, earth_rate: bool, g_of):
    """Steps 1–5 from sample k to k+1: (C_b^n, V, (L, λ, h), V̇) at k+1 from their values at k (a_k = V̇ at k),
    the gyro samples at k and k+1 and the accelerometer sample at k+1."""
    w_ie, w_en = _rates_ned(lat, h, v, earth_rate)
    ux, uy, uz = _rotate(q, (w_ie[0] + w_en[0], w_ie[1] + w_en[1], w_ie[2] + w_en[2]), inverse=True)
    w_nb = (0.5 * (w_k[0] + w_next[0]) - ux, 0.5 * (w_k[1] + w_next[1]) - uy, 0.5 * (w_k[2] + w_next[2]) - uz)
    q_next = _normalised(_quat_product(q, _quat_of_rotvec(w_nb[0] * dt, w_nb[1] * dt, w_nb[2] * dt)))
    v_pred = tuple(v[i] + dt * a_k[i] for i in range(3))
    p_dot_k = _pos_dot(v, lat, h)
    lat_p, lon_p, h_p = lat + dt * p_dot_k[0], lon + dt * p_dot_k[1], h + dt * p_dot_k[2]
    a_next = _v_dot(q_next, f_next, v_pred, lat_p, h_p, earth_rate, g_of)
    v_next = tuple(v[i] + 0.5 * dt * (a_k[i] + a_next[i]) for i in range(3))
    p_dot_next = _pos_dot(v_next, lat_p, h_p)
    position = (lat + 0.5 * dt * (p_dot_k[0] + p_dot_next[0]), lon + 0.5 * dt * (p_dot_k[1] + p_dot_next[1]),
                h + 0.5 * dt * (p_dot_k[2] + p_dot_next[2]))
    return q_next, v_next, position, _v_dot(q_next, f_next, v_next, position[0], position[2], earth_rate, g_of)


@dataclass(frozen=True, eq=False)
class InertialSolution:
    """Inertial-frame navigation output: t_s (n,), q_wxyz (n,4) body→inertial, v_m_s (n,3), p_m (n,3)."""

    t_s: np.ndarray
    q_wxyz: np.ndarray
    v_m_s: np.ndarray
    p_m: np.ndarray


def _prefix_product(increments: Rotation) -> Rotation:
    """[inc0, inc0·inc1, inc0·inc1·inc2, …] by a log-depth scan (vectorised compositions, order kept)."""
    cum = increments
    n = len(cum)
    shift = 1
    while shift < n:
        cum = Rotation.concatenate([cum[:shift], cum[:-shift] * cum[shift:]])
        shift *= 2
    return cum


def mechanise_inertial(t_s, gyro_rad_s, accel_m_s2, q0_wxyz, v0_m_s, p0_m,
                       gravity_i_m_s2=None) -> InertialSolution:
    """Navigation in a non-rotating (inertial) frame (Groves 2nd ed. §5.2; Ghasemzadeh & Heyrani Nobari
    2011, eqs. 43–44).

    C_b^i from the gyros (body-frame increments exp(ω̄ Δt), trapezoidal ω̄), f^i = C_b^i f^b, plus the gravity
    vector `gravity_i_m_s2` if given (the gyro-free paper's scenario has none), integrated twice (trapezoid).
    """
    t = np.asarray(t_s, dtype=float)
    w = np.asarray(gyro_rad_s, dtype=float)
    f = np.asarray(accel_m_s2, dtype=float)
    n = len(t)
    if w.shape != (n, 3) or f.shape != (n, 3) or n < 1:
        raise ValueError("t_s (n,), gyro_rad_s (n,3) and accel_m_s2 (n,3) must have the same length n ≥ 1")
    q0 = np.asarray(q0_wxyz, dtype=float)
    c0 = Rotation.from_quat([q0[1], q0[2], q0[3], q0[0]])
    if n > 1:
        dt = np.diff(t)[:, None]
        inc = Rotation.from_rotvec(0.5 * (w[:-1] + w[1:]) * dt)
        c = Rotation.concatenate([c0, c0 * _prefix_product(inc)])
    else:
        c = Rotation.concatenate([c0])
    a = c.apply(f)
    if gravity_i_m_s2 is not None:
        a = a + np.asarray(gravity_i_m_s2, dtype=float)
    v = np.asarray(v0_m_s, dtype=float) + cumulative_trapezoid(a, t, axis=0, initial=0.0)
    p = np.asarray(p0_m, dtype=float) + cumulative_trapezoid(v, t, axis=0, initial=0.0)
    q = c.as_quat()
    q = np.column_stack([q[:, 3], q[:, :3]])
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return InertialSolution(t, q, v, p)
