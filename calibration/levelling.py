"""Roll and pitch for levelling magnetometer samples: from an attitude estimator run over the recording."""

from __future__ import annotations

import numpy as np

from ahrsd.core.sample import make_sample
from ahrsd.estimator import make_estimator

from .backstepping_paper import BacksteppingError
from .magfit import MagFitInput


def roll_pitch_from_estimator(data: MagFitInput, name: str = "mekf") -> tuple[np.ndarray, np.ndarray]:
    """Run `ahrsd.estimator.make_estimator(name)` over the samples (raw magnetometer: the estimator's design
    keeps magnetometer errors out of roll/pitch) and return its roll and pitch per sample."""
    if data.gyro_rad_s is None or data.accel_m_s2 is None:
        raise BacksteppingError("the estimator needs gyro and accelerometer samples")
    est = make_estimator(name)
    n = len(data)
    roll, pitch = np.empty(n), np.empty(n)
    for i in range(n):
        e = est.update(make_sample(data.t_s[i], data.gyro_rad_s[i], data.accel_m_s2[i], data.mag_ut[i]))
        roll[i], pitch[i] = e.roll_rad, e.pitch_rad
    return roll, pitch
