"""A learned iron's heading offset holds the learning window's yaw error, and its prior says so (issue 28, boat29).

The iron learner fits the field to the WMM's through the filter's attitude: the corrected field's azimuth is off by
the yaw error the filter had while it learned (iron27), an error the learner's covariance does not count. Once the
magnetometer is heard at its weight (test_learned_iron_field_check.py), a prior without it pins the heading to that
copy of the learning window's yaw: the uncalibrated boat's seed 31 at Nairobi (held-out iron) sat ~2° off for
100 s at a σ of ~0.8° (1.06° RMS from 180 s over 900 s). `Ins._iron_offset_shares_yaw_error` gives the harmonic c0
the yaw's variance and covariance when the learned iron's harmonic states start.

Truth is the simulator's attitude. One held-back run, the shortest that shows it: 300 s (the learning ends at
~157 s; the error sits until ~270 s)."""

from __future__ import annotations

import numpy as np
import pytest

from ahrsd.estimator.ins import Ins
from bench.vehicle_accuracy import estimates_in_arrival_order, honesty_site, simulate_vehicle, tilt_heading_errors_deg

NAIROBI = "-1.29,36.82"
SEED, SECONDS = 31, 300.0
FROM_S = 180.0


@pytest.fixture(scope="module")
def errors():
    site, iron = honesty_site(NAIROBI, "held-out")
    run = simulate_vehicle("boat", SECONDS, SEED, site, mag="uncalibrated", iron=iron)
    est = Ins(declination_rad=run.declination_rad, lever_arm_m=run.lever_arm_m,
              mag_calibration_sigma_rad=run.mag_calibration_sigma_rad)
    q = np.empty((len(run.t_s), 4))
    sigma = np.empty(len(run.t_s))
    for k, e in estimates_in_arrival_order(est, run, run.fixes):
        q[k], sigma[k] = e.q_wxyz, e.sigma_rpy_rad[2]
    _, heading_deg = tilt_heading_errors_deg(q, run.truth_q_wxyz, run.declination_rad)
    late = run.t_s >= FROM_S
    return heading_deg[late], np.degrees(sigma[late])


def test_the_heading_is_not_pinned_to_the_learning_windows_yaw(errors):
    """Without the shared prior 1.92° RMS over 180–300 s (its sign flipped: 2.58°); with it 1.33° (σ median 1.01°)."""
    heading_deg, _ = errors
    assert np.sqrt(np.mean(heading_deg ** 2)) < 1.5


def test_its_sigma_covers_it(errors):
    heading_deg, sigma_deg = errors
    assert np.mean(np.abs(heading_deg) > 3.0 * sigma_deg) < 0.01
