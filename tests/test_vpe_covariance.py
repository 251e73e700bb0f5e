"""VISION_POSITION_ESTIMATE's attitude covariance is the honest variance of the attitude it carries: roll and pitch
from the filter's σ, and the yaw's from the σ of the yaw actually sent. While a hot-swapped calibration's heading
change is slewed in (estimator/slewed_yaw.py), the yaw sent is not the filter's and carries its own, larger σ (the
offset still to come counted in); taking the filter's would tell EKF3 the slewed yaw is better than it is.
Expected values: σ² of the numbers given here (MAVLink common.xml: covariance is the upper-right triangle of the
6×6 matrix, row-major; indices 15, 18 and 20 are roll, pitch and yaw)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ahrsd.daemon import messages as msgs

ROLL_SIGMA, PITCH_SIGMA, FILTER_YAW_SIGMA = 0.01, 0.02, 0.05     # rad


class Estimate:
    def __init__(self, sigma_rpy=(ROLL_SIGMA, PITCH_SIGMA, FILTER_YAW_SIGMA)):
        self.q_wxyz = np.array([1.0, 0.0, 0.0, 0.0])
        self.roll_rad, self.pitch_rad, self.yaw_rad = 0.1, -0.05, 1.0
        self.sigma_rpy_rad = np.array(sigma_rpy)


@pytest.mark.parametrize("sent_yaw_sigma", [0.2, 0.01, 0.0])
def test_the_yaw_variance_is_that_of_the_yaw_sent(sent_yaw_sigma):
    m = msgs.vision_position_estimate(Estimate(), 1, 1.3, 0, yaw_sigma_rad=sent_yaw_sigma)
    assert m.yaw == pytest.approx(1.3)
    assert m.covariance[20] == pytest.approx(sent_yaw_sigma ** 2, abs=1e-15)
    assert m.covariance[15] == pytest.approx(ROLL_SIGMA ** 2) and m.covariance[18] == pytest.approx(PITCH_SIGMA ** 2)


def test_without_a_yaw_sigma_of_its_own_the_filters_is_sent():
    m = msgs.vision_position_estimate(Estimate(), 1, 1.0, 0)
    assert m.covariance[20] == pytest.approx(FILTER_YAW_SIGMA ** 2)


def test_an_unknown_yaw_sigma_sends_a_finite_very_uncertain_attitude():
    """A σ that is not finite is no variance EKF3 can use: the attitude is sent as very uncertain, (π/2)² each."""
    m = msgs.vision_position_estimate(Estimate(), 1, 1.0, 0, yaw_sigma_rad=math.inf)
    assert [m.covariance[i] for i in (15, 18, 20)] == pytest.approx([(math.pi / 2) ** 2] * 3)
