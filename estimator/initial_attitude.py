"""The attitude a filter starts from: Davenport's q-method (weighted Wahba) on one sample's gravity and field
directions. Both filters (mekf, ins) initialise with it."""

from __future__ import annotations

import math

import numpy as np

from ahrsd.core.angles import roll_pitch_from_accel

from .rotations import euler_to_quat
from .wahba import davenport_q

# Weighted Wahba initialisation: weights are 1/σ² of the unit directions. Gravity from one accelerometer
# sample: σ ≈ 0.005 rad (0.05 m/s² / g); field direction: σ ≈ 0.05 rad (0.7 µT / 16 µT horizontal, BROAD-class
# magnetometer). The 100:1 ratio lets the field set heading while the tilt comes from gravity.
_INIT_WEIGHT_GRAVITY = 1.0 / 0.005**2
_INIT_WEIGHT_FIELD = 1.0 / 0.05**2
_INIT_WEIGHTS = np.array([_INIT_WEIGHT_GRAVITY, _INIT_WEIGHT_FIELD])


def initial_attitude(accel_m_s2: np.ndarray, mag_ut: np.ndarray | None) -> np.ndarray:
    """Body→NED quaternion from one specific-force and one field sample: Davenport's q-method (weighted
    Wahba) with reference vectors "up" [0, 0, −1] and magnetic north at the measured dip. Without a usable
    field (None, or parallel to gravity) the heading is set to 0 and only the tilt is determined."""
    f = np.asarray(accel_m_s2, dtype=float)
    up_b = f / np.linalg.norm(f)
    if mag_ut is not None:
        m = np.asarray(mag_ut, dtype=float)
        mn = np.linalg.norm(m)
        if mn > 0.0 and np.linalg.norm(np.cross(up_b, m / mn)) > 1e-3:
            sin_dip = min(max(-float(np.dot(up_b, m / mn)), -1.0), 1.0)   # dip: positive down
            cos_dip = math.sqrt(1.0 - sin_dip * sin_dip)
            # the quaternion only (`davenport_q`): the vectors are finite, unit and not parallel, checked above
            return np.asarray(davenport_q(
                np.array([up_b, m / mn]),
                np.array([[0.0, 0.0, -1.0], [cos_dip, 0.0, sin_dip]]),
                _INIT_WEIGHTS,
            ), dtype=float)
    # tilt only (ZYX Euler from the gravity direction; specific force f = C_n^b [0, 0, −g])
    roll, pitch = roll_pitch_from_accel(up_b)
    return np.asarray(euler_to_quat(roll, pitch, 0.0), dtype=float)
