"""The gyro-free accelerometer array of Ghasemzadeh & Heyrani Nobari, "Error Analyses of Inertial Navigation
System Based on Only Accelerometers and Without Gyroscope" (2011): ten single-axis accelerometers on three
arms of length d.

Each accelerometer k at body position r_k with sensing axis u_k reads the specific force of its own point
(rigid-body lever arm, the paper's eq. 4 with the proof mass fixed):

    f_k = u_k · ( f_b + ω̇ × r_k + ω × (ω × r_k) )

where f_b is the specific force at the reference point b. From the ten readings the paper recovers f_b
(eq. 13), p², q², r² (eq. 14), q̇ (eq. 17) and ṗ (eq. 19). The layout (the paper's Fig. 8, whose
image is not available) is reconstructed by checking every printed equation against this kinematics.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# The paper's Fig. 8 as reconstructed: (position in units of d, sensing axis), sensors m1 … m10
SEED001_LAYOUT = (
    ((+1, 0, 0), (1, 0, 0)),   # m1
    ((-1, 0, 0), (1, 0, 0)),   # m2
    ((0, +1, 0), (0, 1, 0)),   # m3
    ((0, -1, 0), (0, 1, 0)),   # m4
    ((0, 0, +1), (0, 0, 1)),   # m5
    ((0, 0, -1), (0, 0, 1)),   # m6
    ((+1, 0, 0), (0, 0, 1)),   # m7: on b1, senses b3
    ((0, 0, +1), (1, 0, 0)),   # m8: on b3, senses b1
    ((0, +1, 0), (0, 0, 1)),   # m9: on b2, senses b3
    ((0, 0, +1), (0, 1, 0)),   # m10: on b3, senses b2
)


@dataclass(frozen=True, eq=False)
class AccelArray:
    """Single-axis accelerometers: positions_m (k,3) from the reference point, unit sensing axes (k,3), body frame."""

    positions_m: np.ndarray
    axes: np.ndarray

    def __post_init__(self):
        p = np.array(self.positions_m, dtype=float)
        a = np.array(self.axes, dtype=float)
        if p.ndim != 2 or p.shape[1] != 3 or a.shape != p.shape:
            raise ValueError("positions_m and axes must both be (k,3)")
        norms = np.linalg.norm(a, axis=1, keepdims=True)
        if np.any(norms == 0) or not np.all(np.isfinite(p)):
            raise ValueError("sensing axes must be non-zero and positions finite")
        object.__setattr__(self, "positions_m", p)
        object.__setattr__(self, "axes", a / norms)

    @classmethod
    def seed001(cls, arm_m: float = 0.1) -> "AccelArray":
        """The paper's ten-accelerometer configuration with arm length d = arm_m (not given in the paper)."""
        pos = np.array([p for p, _ in SEED001_LAYOUT], dtype=float) * arm_m
        ax = np.array([a for _, a in SEED001_LAYOUT], dtype=float)
        return cls(pos, ax)

    def tilted(self, tilt_rotvec_rad) -> "AccelArray":
        """The same array with each sensing axis misaligned by a small rotation (k,3) rad
        (the paper's Sec. 5, eqs. 26–42)."""
        from scipy.spatial.transform import Rotation

        return AccelArray(self.positions_m, Rotation.from_rotvec(np.asarray(tilt_rotvec_rad)).apply(self.axes))

    def specific_force(self, f_ref_m_s2, omega_rad_s, omega_dot_rad_s2) -> np.ndarray:
        """Readings (n,k) for reference-point specific force, body rate and angular acceleration, all (n,3)."""
        f = np.asarray(f_ref_m_s2, dtype=float)[:, None, :]
        w = np.asarray(omega_rad_s, dtype=float)[:, None, :]
        wd = np.asarray(omega_dot_rad_s2, dtype=float)[:, None, :]
        r = self.positions_m[None, :, :]
        f_k = f + np.cross(wd, r) + np.cross(w, np.cross(w, r))
        return np.einsum("nkj,kj->nk", f_k, self.axes)


@dataclass(frozen=True, eq=False)
class GyroFreeSolution:
    """What the paper extracts from the ten readings: f_b (n,3) m/s², rate_sq (n,3) [p², q², r²] in rad²/s²
    (unclamped: noise can make them negative), rate_abs (n,3) |p|, |q|, |r| (clamped at 0), p_dot, q_dot (n,) rad/s²."""

    f_b: np.ndarray
    rate_sq: np.ndarray
    rate_abs: np.ndarray
    p_dot: np.ndarray
    q_dot: np.ndarray


def solve_seed001(readings_m_s2, arm_m: float) -> GyroFreeSolution:
    """f_b, p², q², r², q̇ and ṗ (module doc) from readings (n,10) of the `AccelArray.seed001(arm_m)` layout."""
    f = np.asarray(readings_m_s2, dtype=float)
    if f.ndim != 2 or f.shape[1] != 10:
        raise ValueError("readings must be (n, 10)")
    d = float(arm_m)
    f1, f2, f3, f4, f5, f6, f7, f8, f9, f10 = f.T
    f_b = np.column_stack([(f1 + f2) / 2, (f3 + f4) / 2, (f5 + f6) / 2])            # eq. 13
    rate_sq = np.column_stack([(+f1 - f2 - f3 + f4 - f5 + f6),                        # eq. 14
                               (-f1 + f2 + f3 - f4 - f5 + f6),
                               (-f1 + f2 - f3 + f4 + f5 - f6)]) / (4 * d)
    q_dot = (-f1 - f2 + f5 + f6 - 2 * f7 + 2 * f8) / (4 * d)                         # eq. 17
    p_dot = (f3 + f4 - f5 - f6 + 2 * f9 - 2 * f10) / (4 * d)                         # eq. 19
    return GyroFreeSolution(f_b, rate_sq, np.sqrt(np.maximum(rate_sq, 0.0)), p_dot, q_dot)
