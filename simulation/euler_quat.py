"""ZYX Euler angles as a body→NED quaternion, and NED vectors expressed in body axes by it, without scipy.

The simulated chip's producer (drivers.sim_block_producer) runs in a process of its own for every simulated
daemon, and most scenarios are Euler scenarios: these few products spare each such process the import of
scipy.spatial (docs/simulation.md). They follow scipy's `Rotation` operation for operation — `from_euler("ZYX")`
composes the three elementary quaternions intrinsically with the Hamilton product; `inv().apply(v)` builds the
rotation matrix of the conjugate quaternion and contracts it with the same `np.einsum` (or `np.matmul` for one
rotation) — and take sin and cos from the C library as scipy's compiled code does (`math`: numpy's own loops need
not agree to the last bit on every CPU), so the results are the same bits; tests/test_simulation_euler_quat.py compares them with scipy's.
Quaternions here are scalar last [x, y, z, w], as scipy's.
"""

from __future__ import annotations

import math

import numpy as np


def quat_xyzw_from_euler_zyx(yaw_rad, pitch_rad, roll_rad) -> np.ndarray:
    """(n, 4) quaternions of C_b^n = Rz(yaw) Ry(pitch) Rx(roll), as `Rotation.from_euler("ZYX", ...).as_quat()`."""
    angles = np.column_stack([yaw_rad, pitch_rad, roll_rad]).astype(float, copy=False)
    q = _elementary(2, angles[:, 0])
    q = _hamilton(q, _elementary(1, angles[:, 1]))
    return _hamilton(q, _elementary(0, angles[:, 2]))


def ned_to_body(q_xyzw: np.ndarray, vectors_ned) -> np.ndarray:
    """NED vectors (n, 3) or (3,) in body axes, C_n^b v, (n, 3), as `Rotation.from_quat(q).inv().apply(vectors_ned)`."""
    x, y, z, w = (-q_xyzw[:, 0], -q_xyzw[:, 1], -q_xyzw[:, 2], q_xyzw[:, 3])    # the conjugate: C_n^b
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
    m = np.empty((len(q_xyzw), 3, 3))
    m[:, 0, 0] = x2 - y2 - z2 + w2
    m[:, 1, 0] = 2 * (xy + zw)
    m[:, 2, 0] = 2 * (xz - yw)
    m[:, 0, 1] = 2 * (xy - zw)
    m[:, 1, 1] = - x2 + y2 - z2 + w2
    m[:, 2, 1] = 2 * (yz + xw)
    m[:, 0, 2] = 2 * (xz + yw)
    m[:, 1, 2] = 2 * (yz - xw)
    m[:, 2, 2] = - x2 - y2 + z2 + w2
    v = np.atleast_2d(np.asarray(vectors_ned, dtype=float))
    if len(m) == 1:
        return np.matmul(m, v[0]) if len(v) == 1 else np.matmul(m, v, axes=[(-2, -1), (-1, -2), (-1, -2)])[0]
    return np.einsum("ijk,ik->ij", m, v)


def _elementary(axis: int, angle_rad: np.ndarray) -> np.ndarray:
    """Rotations about one axis: [sin(a/2) on the axis, cos(a/2)]."""
    half = (angle_rad * 0.5).tolist()          # x * 0.5 is x / 2 exactly (a power of two)
    n = len(half)
    q = np.zeros((n, 4))
    q[:, 3] = np.fromiter(map(math.cos, half), np.float64, n)
    q[:, axis] = np.fromiter(map(math.sin, half), np.float64, n)
    return q


def _hamilton(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """p ⊗ q, row by row (the rotation q, then p)."""
    px, py, pz, pw = p.T
    qx, qy, qz, qw = q.T
    cx, cy, cz = py * qz - pz * qy, pz * qx - px * qz, px * qy - py * qx
    return np.column_stack([pw * qx + qw * px + cx, pw * qy + qw * py + cy, pw * qz + qw * pz + cz,
                            pw * qw - px * qx - py * qy - pz * qz])
