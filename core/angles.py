"""Angle and frame helpers every part shares (design §4): wrapping, ZYX Euler from a quaternion, tilt from
the accelerometer, tilt-compensated heading, standard gravity. Pure numpy, radians unless named `_deg`."""

from __future__ import annotations

import numpy as np

TWO_PI = 2.0 * np.pi
STANDARD_GRAVITY_M_S2 = 9.80665   # the conventional g (CGPM 1901); the "g" in mg figures


def _f(a) -> np.ndarray:
    return np.asarray(a, dtype=np.float64)


def wrap_pi(angle_rad):
    """Wrap angles to [−π, π)."""
    return np.mod(_f(angle_rad) + np.pi, TWO_PI) - np.pi


def wrap_2pi(angle_rad):
    """Wrap angles to [0, 2π) (headings)."""
    a = np.mod(_f(angle_rad), TWO_PI)
    # np.mod can return exactly 2π for tiny negative inputs (rounding): fold it back to 0.
    return np.where(a >= TWO_PI, 0.0, a)


def wrap_180_deg(angle_deg):
    """Wrap angles in degrees to [−180, 180)."""
    return np.mod(_f(angle_deg) + 180.0, 360.0) - 180.0
