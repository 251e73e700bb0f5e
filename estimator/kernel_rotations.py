"""Rotation helpers for the compiled kernels (numba), on scalars so a step allocates nothing: the one
quaternion → DCM of both filters, quaternion product, rotation-vector exponential, ZYX Euler angles and the
1σ roll/pitch of a NED tilt covariance. Conventions as `rotations.py` (CONTRIBUTING.md): Hamilton quaternions,
scalar first, rotating body FRD vectors into NED; C_b^n = Rz(yaw) Ry(pitch) Rx(roll).
"""

from __future__ import annotations

import math

from numba import njit


@njit(cache=True)
def dcm(q0, q1, q2, q3):
    """C_b^n of a unit quaternion, as 9 scalars row-major (c00, c01, … c22)."""
    return (1.0 - 2.0 * (q2 * q2 + q3 * q3), 2.0 * (q1 * q2 - q0 * q3), 2.0 * (q1 * q3 + q0 * q2),
            2.0 * (q1 * q2 + q0 * q3), 1.0 - 2.0 * (q1 * q1 + q3 * q3), 2.0 * (q2 * q3 - q0 * q1),
            2.0 * (q1 * q3 - q0 * q2), 2.0 * (q2 * q3 + q0 * q1), 1.0 - 2.0 * (q1 * q1 + q2 * q2))


@njit(cache=True)
def rotate_to_ned(q0, q1, q2, q3, x, y, z):
    """C_b^n(q) · [x, y, z] for the body→NED quaternion q."""
    c00, c01, c02, c10, c11, c12, c20, c21, c22 = dcm(q0, q1, q2, q3)
    return c00 * x + c01 * y + c02 * z, c10 * x + c11 * y + c12 * z, c20 * x + c21 * y + c22 * z


@njit(cache=True)
def quat_mul(a0, a1, a2, a3, b0, b1, b2, b3):
    """The Hamilton product a ⊗ b."""
    return (a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3,
            a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
            a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1,
            a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0)


@njit(cache=True)
def rotvec_quat(rx, ry, rz):
    """exp of a rotation vector (rad) as a unit quaternion."""
    ang = math.sqrt(rx * rx + ry * ry + rz * rz)
    if ang > 1e-9:
        s = math.sin(0.5 * ang) / ang
        return math.cos(0.5 * ang), rx * s, ry * s, rz * s
    return 1.0, 0.5 * rx, 0.5 * ry, 0.5 * rz


@njit(cache=True)
def normalised(q0, q1, q2, q3):
    """q / |q|."""
    n = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    return q0 / n, q1 / n, q2 / n, q3 / n


@njit(cache=True)
def euler_zyx(q0, q1, q2, q3):
    """ZYX roll, pitch, yaw of a body→NED quaternion, rad."""
    roll = math.atan2(2.0 * (q2 * q3 + q0 * q1), 1.0 - 2.0 * (q1 * q1 + q2 * q2))
    pitch = -math.asin(min(1.0, max(-1.0, 2.0 * (q1 * q3 - q0 * q2))))
    yaw = math.atan2(2.0 * (q1 * q2 + q0 * q3), 1.0 - 2.0 * (q2 * q2 + q3 * q3))
    return roll, pitch, yaw


@njit(cache=True)
def tilt_sigma(cy, sy, pnn, pne, pee):
    """1σ roll and pitch: the NED tilt covariance (P_NN, P_NE, P_EE of δθ) rotated into the heading frame
    (cy, sy: cosine and sine of yaw)."""
    sig_roll = math.sqrt(max(cy * cy * pnn + 2.0 * cy * sy * pne + sy * sy * pee, 0.0))
    sig_pitch = math.sqrt(max(sy * sy * pnn - 2.0 * cy * sy * pne + cy * cy * pee, 0.0))
    return sig_roll, sig_pitch


@njit(cache=True)
def euler_and_tilt_sigma(q0, q1, q2, q3, pnn, pne, pee):
    """ZYX roll, pitch, yaw of a body→NED quaternion, and the 1σ roll and pitch from the NED tilt covariance
    (P_NN, P_NE, P_EE of δθ) rotated into the heading frame."""
    roll, pitch, yaw = euler_zyx(q0, q1, q2, q3)
    sig_roll, sig_pitch = tilt_sigma(math.cos(yaw), math.sin(yaw), pnn, pne, pee)
    return roll, pitch, yaw, sig_roll, sig_pitch


@njit(cache=True)
def set_dcm_from_euler(c, yaw, pitch, roll):
    """c ← Rz(yaw) Ry(pitch) Rx(roll) (body → NED)."""
    cy, sy = math.cos(yaw), math.sin(yaw)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cr, sr = math.cos(roll), math.sin(roll)
    c[0, 0] = cy * cp
    c[0, 1] = cy * sp * sr - sy * cr
    c[0, 2] = cy * sp * cr + sy * sr
    c[1, 0] = sy * cp
    c[1, 1] = sy * sp * sr + cy * cr
    c[1, 2] = sy * sp * cr - cy * sr
    c[2, 0] = -sp
    c[2, 1] = cp * sr
    c[2, 2] = cp * cr
