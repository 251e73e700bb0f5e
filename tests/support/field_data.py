"""Synthetic magnetometer data with known hard and soft iron for the field-calibration tests.

Truth from scipy's rotations and the WMM field at one site (never from the code under test).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from scipy.spatial.transform import Rotation

from ahrsd.core.wmm import earth_field

SITE = earth_field(35.7, 51.4, 0.0)  # Tehran-like field, ~48.8 µT, 55° dip
HARD_IRON_UT = np.array([18.0, -9.5, 6.0])                    # a few hundred mgauss
SOFT_DISTORTION = np.array([[1.06, 0.03, -0.02], [0.03, 0.95, 0.015], [-0.02, 0.015, 1.02]])
MAG_NOISE_UT = 0.125  # 1.25 mgauss rms: the ADIS16405 datasheet magnetometer output noise


def level_turns(duration_s=150.0, rate_hz=50.0, turn_period_s=40.0, tilt_deg=8.0, seed=1):
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    yaw = 2 * np.pi * t / turn_period_s
    roll = np.radians(tilt_deg) * np.sin(2 * np.pi * t / 7.0)
    pitch = np.radians(0.75 * tilt_deg) * np.sin(2 * np.pi * t / 11.0 + 0.4)
    return trajectory(t, roll, pitch, yaw, seed)


def tumble(duration_s=120.0, rate_hz=50.0, seed=2):
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    yaw = 2 * np.pi * t / 17.0
    pitch = np.radians(85.0) * np.sin(2 * np.pi * t / 23.0)
    roll = 2 * np.pi * t / 13.0
    return trajectory(t, roll, pitch, yaw, seed)


def trajectory(t, roll, pitch, yaw, seed=0):
    """Raw (iron-distorted, noisy) and true body field and the specific force at rest along Euler angles
    (ZYX, body -> true-north NED, scipy)."""
    rng = np.random.default_rng(seed)
    rot = Rotation.from_euler("ZYX", np.column_stack([yaw, pitch, roll]))  # body -> NED
    true_body = rot.inv().apply(SITE.ned_ut)
    raw = true_body @ SOFT_DISTORTION.T + HARD_IRON_UT + rng.normal(0, MAG_NOISE_UT, true_body.shape)
    accel = rot.inv().apply([0.0, 0.0, -9.80665])  # specific force at rest, NED up = −z
    return SimpleNamespace(t=t, roll=roll, pitch=pitch, yaw=yaw, raw=raw, accel=accel, true_body=true_body)
