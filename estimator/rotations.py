"""Rotation maths on ahrsd's conventions (CONTRIBUTING.md).

Frames: navigation NED, body FRD. Quaternions are Hamilton, **scalar first** ``[w, x, y, z]``, and rotate
body vectors into NED: ``v_ned = q ⊗ v_body ⊗ q*`` = ``C_b^n v_body``. Euler angles are ZYX (yaw, pitch, roll):
``C_b^n = Rz(yaw) Ry(pitch) Rx(roll)``, and from C_b^n:
roll = atan2(C32, C33), pitch = −asin(C31), yaw = atan2(C21, C11).

Every function is pure and works on numpy arrays; quaternion, vector and DCM arguments may carry leading
axes (shape ``(..., 4)``, ``(..., 3)``, ``(..., 3, 3)``) and broadcast where that is cheap. Angles are radians.
Ghasemzadeh & Heyrani Nobari (2011, gyro-free INS) write quaternions scalar last ``[ε1, ε2, ε3, ε4]`` (their
eq 43–44, Hamilton):
convert at that boundary with :func:`quat_from_scalar_last` / :func:`quat_to_scalar_last`.
"""

from __future__ import annotations

import math

import numpy as np



# Below this rotation angle the exp/log maps use their Taylor series (avoids 0/0; error ~θ⁴ ≪ 1e-16).
_SMALL_ANGLE_RAD = 1e-6


def _f(a) -> np.ndarray:
    return np.asarray(a, dtype=np.float64)


# ------------------------------------------------------------------------------------------ quaternions
def quat_normalize(q) -> np.ndarray:
    """Unit quaternion(s) q/|q|."""
    q = _f(q)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quat_canonical(q) -> np.ndarray:
    """The same rotation with w ≥ 0 (q and −q are one rotation)."""
    q = _f(q)
    return np.where(q[..., :1] < 0.0, -q, q)


def quat_conjugate(q) -> np.ndarray:
    """q* = [w, −x, −y, −z]: the inverse rotation of a unit quaternion (NED→body if q is body→NED)."""
    q = _f(q)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def quat_multiply(p, q) -> np.ndarray:
    """Hamilton product p ⊗ q. As rotations: apply q first, then p (C(p⊗q) = C(p)·C(q))."""
    p, q = _f(p), _f(q)
    pw, px, py, pz = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    qw, qx, qy, qz = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        (
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ),
        axis=-1,
    )


def quat_rotate(q, v) -> np.ndarray:
    """Rotate vector(s) v by unit quaternion(s) q: q ⊗ [0, v] ⊗ q* (body → NED for an attitude q)."""
    q, v = _f(q), _f(v)
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def quat_to_dcm(q) -> np.ndarray:
    """DCM C_b^n (…, 3, 3) of unit quaternion(s) q (body→NED). Same matrix as
    Ghasemzadeh & Heyrani Nobari eq 44 with ε4 = w."""
    q = _f(q)
    if q.shape == (4,):
        # one quaternion in Python floats: the per-element array indexing costs most of a single conversion
        return np.array(_dcm_rows(*q.tolist()))
    c = np.empty(q.shape[:-1] + (3, 3))
    for i, row in enumerate(_dcm_rows(q[..., 0], q[..., 1], q[..., 2], q[..., 3])):
        for j, entry in enumerate(row):
            c[..., i, j] = entry
    return c


def _dcm_rows(w, x, y, z):
    """The rows of `quat_to_dcm`'s matrix from the quaternion's components, floats or arrays alike (the same
    products and sums in the same order either way, so the same matrix to the bit)."""
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    return ((1.0 - 2.0 * (yy + zz), 2.0 * (xy - wz), 2.0 * (xz + wy)),
            (2.0 * (xy + wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz - wx)),
            (2.0 * (xz - wy), 2.0 * (yz + wx), 1.0 - 2.0 * (xx + yy)))


def dcm_to_quat(c) -> np.ndarray:
    """Unit quaternion(s) (w ≥ 0) of rotation matrix(ces) C (Shepperd's method: stable for every rotation).

    C need not be exactly orthonormal; the result is normalised (close to the nearest rotation for small errors).
    """
    c = _f(c)
    if c.shape == (3, 3):
        return _dcm_to_quat_one(c)
    c11, c22, c33 = c[..., 0, 0], c[..., 1, 1], c[..., 2, 2]
    tr = c11 + c22 + c33
    # Four candidate formulas; each is well conditioned where its pivot is the largest.
    cand = np.stack(
        (
            np.stack((1.0 + tr, c[..., 2, 1] - c[..., 1, 2], c[..., 0, 2] - c[..., 2, 0], c[..., 1, 0] - c[..., 0, 1]), -1),
            np.stack((c[..., 2, 1] - c[..., 1, 2], 1.0 + c11 - c22 - c33, c[..., 0, 1] + c[..., 1, 0], c[..., 0, 2] + c[..., 2, 0]), -1),
            np.stack((c[..., 0, 2] - c[..., 2, 0], c[..., 0, 1] + c[..., 1, 0], 1.0 - c11 + c22 - c33, c[..., 1, 2] + c[..., 2, 1]), -1),
            np.stack((c[..., 1, 0] - c[..., 0, 1], c[..., 0, 2] + c[..., 2, 0], c[..., 1, 2] + c[..., 2, 1], 1.0 - c11 - c22 + c33), -1),
        ),
        axis=-2,
    )
    pivot = np.argmax(np.stack((tr, c11, c22, c33), -1), axis=-1)
    q = np.take_along_axis(cand, pivot[..., None, None], axis=-2)[..., 0, :]
    return quat_canonical(quat_normalize(q))


def _dcm_to_quat_one(c: np.ndarray) -> np.ndarray:
    return np.array(dcm_rows_to_quat(c.tolist()))


def dcm_rows_to_quat(c) -> tuple[float, float, float, float]:
    """Shepperd's method on one DCM given as three rows of floats, scalar maths (for per-sample hot paths: numpy's
    per-call overhead dominates on one 3×3 matrix); returns (w, x, y, z) normalised, w ≥ 0. Same as `dcm_to_quat`."""
    (c11, c12, c13), (c21, c22, c23), (c31, c32, c33) = c
    tr = c11 + c22 + c33
    if tr >= c11 and tr >= c22 and tr >= c33:
        w, x, y, z = 1.0 + tr, c32 - c23, c13 - c31, c21 - c12
    elif c11 >= c22 and c11 >= c33:
        w, x, y, z = c32 - c23, 1.0 + c11 - c22 - c33, c12 + c21, c13 + c31
    elif c22 >= c33:
        w, x, y, z = c13 - c31, c12 + c21, 1.0 - c11 + c22 - c33, c23 + c32
    else:
        w, x, y, z = c21 - c12, c13 + c31, c23 + c32, 1.0 - c11 - c22 + c33
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if w < 0.0:
        n = -n
    return w / n, x / n, y / n, z / n


# --------------------------------------------------------------------------------------------- Euler
def euler_to_dcm(roll_rad, pitch_rad, yaw_rad) -> np.ndarray:
    """C_b^n = Rz(yaw)·Ry(pitch)·Rx(roll) (full form)."""
    cr, sr = np.cos(_f(roll_rad)), np.sin(_f(roll_rad))
    cp, sp = np.cos(_f(pitch_rad)), np.sin(_f(pitch_rad))
    cy, sy = np.cos(_f(yaw_rad)), np.sin(_f(yaw_rad))
    cr, sr, cp, sp, cy, sy = np.broadcast_arrays(cr, sr, cp, sp, cy, sy)
    c = np.empty(cr.shape + (3, 3))
    c[..., 0, 0] = cp * cy
    c[..., 0, 1] = -cr * sy + sr * sp * cy
    c[..., 0, 2] = sr * sy + cr * sp * cy
    c[..., 1, 0] = cp * sy
    c[..., 1, 1] = cr * cy + sr * sp * sy
    c[..., 1, 2] = -sr * cy + cr * sp * sy
    c[..., 2, 0] = -sp
    c[..., 2, 1] = sr * cp
    c[..., 2, 2] = cr * cp
    return c


def dcm_to_euler(c) -> np.ndarray:
    """ZYX Euler angles [roll, pitch, yaw] (…, 3) from C_b^n (yaw in [−π, π])."""
    c = _f(c)
    roll = np.arctan2(c[..., 2, 1], c[..., 2, 2])
    pitch = -np.arcsin(np.clip(c[..., 2, 0], -1.0, 1.0))
    yaw = np.arctan2(c[..., 1, 0], c[..., 0, 0])
    return np.stack((roll, pitch, yaw), axis=-1)


def euler_to_quat(roll_rad, pitch_rad, yaw_rad) -> np.ndarray:
    """Quaternion qz(yaw) ⊗ qy(pitch) ⊗ qx(roll) (body→NED)."""
    hr, hp, hy = 0.5 * _f(roll_rad), 0.5 * _f(pitch_rad), 0.5 * _f(yaw_rad)
    cr, sr, cp, sp, cy, sy = np.cos(hr), np.sin(hr), np.cos(hp), np.sin(hp), np.cos(hy), np.sin(hy)
    return np.stack(
        (
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ),
        axis=-1,
    )


def quat_to_euler(q) -> np.ndarray:
    """ZYX Euler angles [roll, pitch, yaw] (…, 3) of unit quaternion(s), via the DCM elements of dcm_to_euler."""
    q = _f(q)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    roll = np.arctan2(2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y))
    pitch = -np.arcsin(np.clip(2.0 * (x * z - w * y), -1.0, 1.0))
    yaw = np.arctan2(2.0 * (x * y + w * z), 1.0 - 2.0 * (y * y + z * z))
    return np.stack((roll, pitch, yaw), axis=-1)


# ------------------------------------------------------------------------------- exponential / log map
def quat_exp(rotvec_rad) -> np.ndarray:
    """Unit quaternion of a rotation vector θ·u (axis u, angle θ): [cos θ/2, sin(θ/2)·u]."""
    v = _f(rotvec_rad)
    if v.shape == (3,):
        x, y, z = v.tolist()
        theta = math.sqrt((x * x + y * y) + z * z)
        if not math.isinf(theta):          # (math.sin(inf) raises where np.sin gives NaN)
            return _quat_exp_one(x, y, z, theta)
    theta = np.linalg.norm(v, axis=-1, keepdims=True)
    small = theta < _SMALL_ANGLE_RAD
    safe = np.where(small, 1.0, theta)
    half_sinc_small, w_small = _small_angle_exp(theta)
    half_sinc = np.where(small, half_sinc_small, np.sin(0.5 * safe) / safe)  # sin(θ/2)/θ
    w = np.where(small, w_small, np.cos(0.5 * theta))
    return np.concatenate((w, half_sinc * v), axis=-1)


def _small_angle_exp(theta):
    """sin(θ/2)/θ and cos(θ/2) by their series to θ² (below _SMALL_ANGLE_RAD), for a float or an array."""
    return 0.5 - theta * theta / 48.0, 1.0 - theta * theta / 8.0


def _quat_exp_one(x: float, y: float, z: float, theta: float) -> np.ndarray:
    """`quat_exp` of one rotation vector (x, y, z) of norm theta = √((x² + y²) + z²), summed as numpy sums it here,
    in Python floats, without the array machinery that costs most of a single call: the same operations in the same
    order (math's sin and cos are the C library's, as numpy's float64 ones on this machine), so the same quaternion
    to the bit here (tests/test_rotations.py), elsewhere within an ulp or two."""
    if theta < _SMALL_ANGLE_RAD:
        half_sinc, w = _small_angle_exp(theta)
    else:
        half_sinc = math.sin(0.5 * theta) / theta
        w = math.cos(0.5 * theta)
    return np.array((w, half_sinc * x, half_sinc * y, half_sinc * z))


def quat_log(q) -> np.ndarray:
    """Rotation vector (…, 3) of unit quaternion(s), angle in [0, π] (q and −q give the same vector)."""
    q = quat_canonical(q)
    w = q[..., :1]
    u = q[..., 1:]
    s = np.linalg.norm(u, axis=-1, keepdims=True)
    small = s < _SMALL_ANGLE_RAD
    safe = np.where(small, 1.0, s)
    w_safe = np.where(small, w, 1.0)  # w ≈ 1 wherever s is small (unit quaternion)
    factor = np.where(small, 2.0 / w_safe * (1.0 - s * s / (3.0 * w_safe * w_safe)), 2.0 * np.arctan2(s, w) / safe)
    return factor * u


def rotvec_to_dcm(rotvec_rad) -> np.ndarray:
    """DCM of a rotation vector (Rodrigues, via the quaternion)."""
    return quat_to_dcm(quat_exp(rotvec_rad))


def dcm_to_rotvec(c) -> np.ndarray:
    """Rotation vector of a DCM."""
    return quat_log(dcm_to_quat(c))


def quat_integrate(q, omega_body_rad_s, dt_s) -> np.ndarray:
    """Propagate attitude q (body→NED) by a constant body rate over dt: q ⊗ exp(ω·dt)."""
    return quat_multiply(q, quat_exp(_f(omega_body_rad_s) * _f(dt_s)[..., None]))


# ------------------------------------------------------------------------------------ matrices / misc
def skew(v) -> np.ndarray:
    """Cross-product matrix [v×] (…, 3, 3): skew(a) @ b == cross(a, b)."""
    v = _f(v)
    if v.shape == (3,):
        # one vector (per GNSS fix): built from Python floats, the element-wise assignments below cost most of it;
        # the same negations and zeros, so the same matrix to the bit
        x, y, z = v.tolist()
        return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    s = np.zeros(v.shape[:-1] + (3, 3))
    s[..., 0, 1], s[..., 0, 2] = -v[..., 2], v[..., 1]
    s[..., 1, 0], s[..., 1, 2] = v[..., 2], -v[..., 0]
    s[..., 2, 0], s[..., 2, 1] = -v[..., 1], v[..., 0]
    return s


def reorthonormalize(c, iterations: int = 1) -> np.ndarray:
    """The re-orthonormalisation the thesis filter uses: C ← 1.5·C − 0.5·C·Cᵀ·C, `iterations` times.

    Each step is one Newton–Schulz step towards the orthogonal polar factor of C (the nearest orthogonal
    matrix); it converges quadratically when the singular values of C lie in (0, √3).
    """
    c = _f(c)
    for _ in range(iterations):
        c = 1.5 * c - 0.5 * c @ np.swapaxes(c, -1, -2) @ c
    return c


def reorthonormalize_rows(c):
    """One re-orthonormalisation, C ← 1.5C − 0.5CCᵀC = C(1.5I − 0.5CᵀC), on one 3×3 given as three rows of floats
    (scalar maths for per-sample hot paths; same result as `reorthonormalize(c, 1)`). Returns three row tuples."""
    (c00, c01, c02), (c10, c11, c12), (c20, c21, c22) = c
    s00 = c00 * c00 + c10 * c10 + c20 * c20
    s11 = c01 * c01 + c11 * c11 + c21 * c21
    s22 = c02 * c02 + c12 * c12 + c22 * c22
    s01 = c00 * c01 + c10 * c11 + c20 * c21
    s02 = c00 * c02 + c10 * c12 + c20 * c22
    s12 = c01 * c02 + c11 * c12 + c21 * c22
    t00, t11, t22 = 1.5 - 0.5 * s00, 1.5 - 0.5 * s11, 1.5 - 0.5 * s22
    t01, t02, t12 = -0.5 * s01, -0.5 * s02, -0.5 * s12
    return ((c00 * t00 + c01 * t01 + c02 * t02, c00 * t01 + c01 * t11 + c02 * t12, c00 * t02 + c01 * t12 + c02 * t22),
            (c10 * t00 + c11 * t01 + c12 * t02, c10 * t01 + c11 * t11 + c12 * t12, c10 * t02 + c11 * t12 + c12 * t22),
            (c20 * t00 + c21 * t01 + c22 * t02, c20 * t01 + c21 * t11 + c22 * t12, c20 * t02 + c21 * t12 + c22 * t22))


def orthonormality_error(c) -> np.ndarray:
    """max |CᵀC − I| per matrix: 0 for a rotation (or reflection)."""
    c = _f(c)
    return np.max(np.abs(np.swapaxes(c, -1, -2) @ c - np.eye(3)), axis=(-2, -1))


def quat_from_scalar_last(q_xyzw) -> np.ndarray:
    """The gyro-free paper's / scipy's scalar-last [x, y, z, w] (ε1, ε2, ε3, ε4) → ahrsd's [w, x, y, z]."""
    q = _f(q_xyzw)
    return q[..., [3, 0, 1, 2]]


def quat_to_scalar_last(q_wxyz) -> np.ndarray:
    """ahrsd's [w, x, y, z] → scalar-last [x, y, z, w] (the gyro-free paper's ε1..ε4, scipy's as_quat())."""
    q = _f(q_wxyz)
    return q[..., [1, 2, 3, 0]]


def quat_angle_between(p, q) -> np.ndarray:
    """Angle (rad, in [0, π]) of the rotation taking p to q: 2·atan2(|vec(p*⊗q)|, |w(p*⊗q)|)."""
    d = quat_multiply(quat_conjugate(p), q)
    return 2.0 * np.arctan2(np.linalg.norm(d[..., 1:], axis=-1), np.abs(d[..., 0]))


def dcm_angle_between(a, b) -> np.ndarray:
    """Angle (rad) of the rotation taking DCM a to DCM b (via the quaternion: accurate near 0 and π)."""
    return quat_angle_between(dcm_to_quat(a), dcm_to_quat(b))


__all__ = [
    "quat_normalize", "quat_canonical", "quat_conjugate", "quat_multiply",
    "quat_rotate", "quat_to_dcm", "dcm_to_quat", "euler_to_dcm", "dcm_to_euler", "euler_to_quat",
    "quat_to_euler", "quat_exp", "quat_log", "rotvec_to_dcm", "dcm_to_rotvec", "quat_integrate", "skew",
    "reorthonormalize", "reorthonormalize_rows", "dcm_rows_to_quat", "orthonormality_error", "quat_from_scalar_last", "quat_to_scalar_last",
    "quat_angle_between", "dcm_angle_between",
]
