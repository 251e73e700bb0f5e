"""Orientations for multi-position accelerometer calibration tests: which body vector points up."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from ahrsd.calibration.accel_cal import GUIDED_TARGETS


def up_vectors(n_random: int = 0) -> np.ndarray:
    """The 6 faces + 8 corners of the guided procedure, 12 edge midpoints, and optional random ones."""
    faces_corners = [d for _, d in GUIDED_TARGETS]
    edges = [v for v in ([a, b, 0] for a in (1, -1) for b in (1, -1))] + \
            [[a, 0, b] for a in (1, -1) for b in (1, -1)] + [[0, a, b] for a in (1, -1) for b in (1, -1)]
    u = np.vstack([np.array(faces_corners, float), np.array(edges, float)])
    if n_random:
        u = np.vstack([u, Rotation.random(n_random, random_state=3).apply([0, 0, 1])])
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def roll_pitch_for_up(u: np.ndarray) -> tuple[float, float]:
    """(roll, pitch) in degrees that make the accelerometer read +g along the body vector u."""
    return math.degrees(math.atan2(-u[1], -u[2])), math.degrees(math.asin(np.clip(u[0], -1, 1)))
