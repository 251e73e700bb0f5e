"""Angle and frame helpers every part shares (NED/FRD axes, ZYX Euler angles): wrapping, tilt from the
accelerometer, the body direction of NED down, tilt-compensated heading, the Euler yaw rate, standard gravity.
Pure numpy, radians unless named `_deg`."""

from __future__ import annotations

import math

import numpy as np

TWO_PI = 2.0 * np.pi
STANDARD_GRAVITY_M_S2 = 9.80665   # the conventional g (CGPM 1901); the "g" in mg figures


def _f(a) -> np.ndarray:
    return np.asarray(a, dtype=np.float64)


def wrap_pi(angle_rad):
    """Wrap angles to [−π, π)."""
    return np.mod(_f(angle_rad) + np.pi, TWO_PI) - np.pi


def wrap_pi_float(angle_rad: float) -> float:
    """One angle (a Python float) wrapped to [−π, π), without numpy's per-call cost: the per-check scalar paths
    (the heading monitor, the step test, the NMEA variation)."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


def wrap_2pi(angle_rad):
    """Wrap angles to [0, 2π) (headings)."""
    a = np.mod(_f(angle_rad), TWO_PI)
    # np.mod can return exactly 2π for tiny negative inputs (rounding): fold it back to 0.
    return np.where(a >= TWO_PI, 0.0, a)


def wrap_180_deg(angle_deg):
    """Wrap angles in degrees to [−180, 180)."""
    return np.mod(_f(angle_deg) + 180.0, 360.0) - 180.0


# ------------------------------------------------------------------------------ tilt and heading (ZYX Euler)


def roll_pitch_from_accel(accel_m_s2):
    """Roll and pitch (rad) of the FRD body from specific force (+g on the up axis at rest, so
    f = C_n^b·[0, 0, −g]): roll = atan2(−f_y, −f_z), pitch = atan2(f_x, √(f_y² + f_z²)). Works on one
    vector (3,) or rows (n, 3). Only valid when the vehicle is not accelerating."""
    f = _f(accel_m_s2)
    roll = np.arctan2(-f[..., 1], -f[..., 2])
    pitch = np.arctan2(f[..., 0], np.hypot(f[..., 1], f[..., 2]))
    return roll, pitch


def down_in_body(roll_rad, pitch_rad) -> np.ndarray:
    """Unit vector of NED down expressed in the body frame: the third row of C_b^n, (…, 3)."""
    r, p = _f(roll_rad), _f(pitch_rad)
    return np.stack((-np.sin(p), np.sin(r) * np.cos(p), np.cos(r) * np.cos(p)), axis=-1)


def tilt_compensated_heading_rad(mag_ut, roll_rad, pitch_rad) -> np.ndarray:
    """Magnetic heading (rad, (−π, π]) from the body-frame field and roll/pitch: the field rotated to the
    local level frame (X_h, Y_h), ψ = atan2(−Y_h, X_h). Vectorised over rows of `mag_ut` (n, 3)."""
    m = np.atleast_2d(_f(mag_ut))
    phi, theta = _f(roll_rad), _f(pitch_rad)
    sp, cp, st, ct = np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta)
    xh = m[:, 0] * ct + m[:, 1] * sp * st + m[:, 2] * cp * st
    yh = m[:, 1] * cp - m[:, 2] * sp
    return np.arctan2(-yh, xh)


def yaw_rate_ned_rad_s(rate_body_rad_s, roll_rad: float, pitch_rad: float) -> float:
    """ψ̇ from body rates (ZYX Euler kinematics): (q sinφ + r cosφ) / cosθ; 0 near θ = ±90°."""
    q, r = float(rate_body_rad_s[1]), float(rate_body_rad_s[2])
    c = math.cos(pitch_rad)
    if abs(c) < 1e-3:
        return 0.0
    return (q * math.sin(roll_rad) + r * math.cos(roll_rad)) / c
