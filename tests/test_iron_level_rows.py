"""IronLearner.level_heading_rows against the heading a level vehicle's magnetometer gives, differentiated
numerically: the rows at two yaw arrays of the same shape asked one after the other (the level attitudes are
made once per yaw array), at two fields asked one after the other (what depends on the field and the yaws alone is
made once per field and yaw array) and at a learned soft iron."""

import math

import numpy as np
import pytest

from ahrsd.estimator.heading_monitor import N_IRON, IronLearner

FIELD_NED_UT = np.array([18.0, 2.5, 45.0])
OTHER_FIELD_NED_UT = np.array([-4.0, 21.0, -30.0])      # another site's: the heading's gradient turned


def _level_heading(truth: np.ndarray, learned: np.ndarray, yaw_rad: float,
                   field: np.ndarray = FIELD_NED_UT) -> float:
    """The magnetometer heading (rad: the yaw less the turn of the read field from the Earth's) a level vehicle at yaw
    reads from a magnetometer with the iron `truth` (b, D), m =
    (I + D) C_bnᵀ B + b, corrected with the iron `learned`: C_bn (I + D̂)⁻¹ (m − b̂)."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    c_bn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    m = (np.eye(3) + truth[3:].reshape(3, 3)) @ c_bn.T @ field + truth[0:3]
    n = c_bn @ np.linalg.solve(np.eye(3) + learned[3:].reshape(3, 3), m - learned[0:3])
    return yaw_rad - (math.atan2(n[1], n[0]) - math.atan2(field[1], field[0]))


@pytest.mark.parametrize("soft", [0.0, 0.05])
def test_rows_are_the_heading_derivative_at_each_yaw(soft):
    learner = IronLearner(prior_sigma_ut=5.0, soft_prior_sigma=0.1)
    rng = np.random.default_rng(3)
    learner.state = np.r_[rng.normal(0.0, 2.0, 3), soft * rng.normal(0.0, 1.0, 9)]
    cases = [(FIELD_NED_UT, np.linspace(0.0, 2.0 * math.pi, 16, endpoint=False)),
             (FIELD_NED_UT, np.linspace(0.3, 5.0, 16)), (OTHER_FIELD_NED_UT, np.linspace(0.3, 5.0, 16))]
    for field, yaw in cases:
        rows = learner.level_heading_rows(field, yaw)
        assert rows.shape == (len(yaw), N_IRON)
        for k, psi in enumerate(yaw):
            numeric = np.empty(N_IRON)
            for j in range(N_IRON):
                step = np.zeros(N_IRON)
                step[j] = 1e-6
                numeric[j] = (_level_heading(learner.state, learner.state + step, psi, field)
                              - _level_heading(learner.state, learner.state - step, psi, field)) / 2e-6
            np.testing.assert_allclose(rows[k], numeric, rtol=1e-4, atol=1e-9)
