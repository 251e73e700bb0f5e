"""The iron-step test (estimator/mag_step.py) weighs the innovation's step against what the gyro may have drifted
over the test's span: the filter's heading between the windows moves with the integrated gyro, whose vertical
bias (σ_b, rad/s) adds σ_b·span of heading and its angle random walk (N, rad/s/√Hz) N·√span. A step the gyro's
own uncertainty could make is no iron step.

Worked numbers (the module docstring's variance, by hand): checks at 4.9 Hz, windows 5 s + 2 s, so a full window
holds checks over a span of 34/4.9 = 6.94 s; the innovation alternates ±a (a = 0.002 rad: its white part gives
2a²·(1/25 + 1/10) = 1.1e-6 rad², gate 5σ = 0.0053 rad, as in tests/test_mag_step.py).
- σ_b = 0.001 rad/s: + (0.001·6.94)² = 4.8e-5 rad², the gate 5·√(4.9e-5) = 0.035 rad;
- N = 0.005 rad/s/√Hz: + 0.005²·6.94 = 1.7e-4 rad², the gate 5·√(1.7e-4) = 0.066 rad.
A step of 0.02 rad (declared at once without them) stays below both gates however long it lasts; a step of
0.2 rad is beyond both."""

from __future__ import annotations

import numpy as np
import pytest

from ahrsd.estimator.mag_step import MagStepDetector

RATE_HZ = 4.9
NOISE_RAD = 0.002


def detections(innovations, gyro_bias_var_rad2_s2=0.0, gyro_arw_rad_s_sqrt_hz=0.0):
    det = MagStepDetector()
    found = []
    for k, inn in enumerate(innovations):
        step = det.add(k / RATE_HZ, inn, 0.0, 0.0, 0.0, 0.0, gyro_bias_var_rad2_s2, gyro_arw_rad_s_sqrt_hz)
        if step is not None:
            found.append(k)
    return found


def innovations(step_rad, n_before=60, n_after=30):
    alternating = NOISE_RAD * (-1.0) ** np.arange(n_before + n_after)
    return alternating + np.r_[np.zeros(n_before), np.full(n_after, step_rad)]


def test_without_gyro_uncertainty_a_small_step_is_declared():
    assert detections(innovations(0.02)) == [62]


@pytest.mark.parametrize("gyro", [dict(gyro_bias_var_rad2_s2=0.001 ** 2), dict(gyro_arw_rad_s_sqrt_hz=0.005)],
                         ids=["bias", "random walk"])
def test_a_step_the_gyro_could_have_drifted_is_no_iron_step(gyro):
    assert detections(innovations(0.02), **gyro) == []
    assert len(detections(innovations(0.2), **gyro)) == 1
