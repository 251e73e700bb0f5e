"""A level vehicle turning through known headings at Anchorage (H about 15 µT, where the learned magnetometer is never
trusted and is fused while its iron is learned), with a known non-symmetric iron applied to the WMM field at the true
attitude: the learned-iron tests' truth, computed without the code under test."""

from __future__ import annotations

import math

import numpy as np

from ahrsd.simulation import Site

FIELD_NED_UT = np.asarray(Site.parse("61.22,-149.90").earth_field().ned_ut, dtype=float)
HARD_IRON_UT = np.array([6.0, -4.0, 3.0])
SOFT_IRON = np.array([[1.04, 0.02, 0.0], [-0.01, 0.97, 0.01], [0.0, 0.02, 1.0]])
CHECK_S = 0.2                   # the heading checks' period, s
HEADINGS_RAD = np.linspace(0.0, 2.0 * math.pi, 16, endpoint=False)


def level(yaw_rad: float) -> np.ndarray:
    """Body → NED of a level vehicle at `yaw_rad`."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def measured(yaw_rad: float) -> np.ndarray:
    """What the magnetometer reads (µT, body) at `yaw_rad`, level: the iron applied to the field."""
    return SOFT_IRON @ (level(yaw_rad).T @ FIELD_NED_UT) + HARD_IRON_UT
