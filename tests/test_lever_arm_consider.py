"""The antenna arm's own uncertainty in the GNSS fusion (estimator/lever_arm_consider.py, ins_core.py
`_arm_consider`): the fixes' noise gains what the arm's error makes of them, so that a car told no arm, its antenna a
metre aft and two up, publishes a heading whose σ covers its error. Truth: the antenna velocity's covariance by
scipy's rotation and numpy's cross product (v_ant = v + C (ω × r), Groves eq. 14.123); the simulator's attitude."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.estimator import ins_core as core
from ahrsd.estimator.ins import InsParams
from ahrsd.estimator.lever_arm_consider import ARM_TERM_CORRELATION_S, arm_covariance_m2
from ahrsd.estimator.lever_arm_fit import PRIOR_SIGMA_M

MAST_M = (-1.0, 0.0, -2.0)       # the antenna 1 m aft and 2 m up (body FRD), as bench/lever_arm_heading.py's


def test_the_arms_error_adds_its_antenna_velocity_and_position_covariance():
    rng = np.random.default_rng(3)
    c = Rotation.from_euler("ZYX", [40.0, 5.0, -8.0], degrees=True).as_matrix()
    w = np.array([0.05, -0.1, 0.3])
    a = rng.normal(size=(3, 3))
    p_arm = a @ a.T
    par = np.zeros(1, core.INS_PARAMS_DTYPE)
    par[0]["lever_arm_cov_m2"] = p_arm
    par[0]["lever_arm_corr_s"] = 1.0
    add_v, add_p = core._arm_consider(par[0], c.reshape(9), w[0], w[1], w[2], 1.0)
    # the covariance of C (ω × δr) and C δr over draws of δr ~ N(0, P_arm)
    draws = rng.multivariate_normal(np.zeros(3), p_arm, size=200_000)
    vel = np.cross(w, draws) @ c.T
    pos = draws @ c.T
    np.testing.assert_allclose(add_v, np.cov(vel.T), atol=0.02 * np.abs(add_v).max())
    np.testing.assert_allclose(add_p, np.cov(pos.T), atol=0.02 * np.abs(add_p).max())


def test_the_arms_term_is_one_error_per_correlation_span_whatever_the_fix_rate():
    c = np.eye(3)
    par = np.zeros(1, core.INS_PARAMS_DTYPE)
    par[0]["lever_arm_cov_m2"] = np.eye(3)
    par[0]["lever_arm_corr_s"] = ARM_TERM_CORRELATION_S
    at = {dt: core._arm_consider(par[0], c.reshape(9), 0.0, 0.0, 0.3, dt)[0] for dt in (0.1, 0.2, 2.0)}
    # n fixes a span fused with n times the variance: the span's information is the same at 10 and 5 Hz
    np.testing.assert_allclose(at[0.1] * 0.1, at[0.2] * 0.2)
    np.testing.assert_allclose(at[0.2][0, 0], 0.09 * ARM_TERM_CORRELATION_S / 0.2)
    np.testing.assert_allclose(at[2.0][0, 0], 0.09)       # fixes further apart than the span: each its own error


def test_the_arms_sigma_is_its_covariance_and_none_by_default():
    np.testing.assert_allclose(arm_covariance_m2(0.2), 0.04 * np.eye(3))
    np.testing.assert_allclose(arm_covariance_m2(math.nan), np.zeros((3, 3)))
    np.testing.assert_allclose(InsParams().to_array(0.0)[0]["lever_arm_cov_m2"], np.zeros((3, 3)))


def car_told_none(seed: int, params: dict, every: int = 4) -> float:
    """ins on the simulated car (ADIS16405, uncalibrated magnetometer, default site, 100 Hz, 300 s) told no antenna
    arm while its receiver's is at MAST_M: the share of its known headings from 120 s whose error is beyond 3σ,
    read at every `every`-th sample (the others stepped without building an estimate, which changes none:
    estimator/estimate_view.py)."""
    from ahrsd.core.sample import make_sample
    from ahrsd.estimator import make_estimator
    from ahrsd.estimator.fix_feed import GnssFixFeed
    from ahrsd.simulation import DEFAULT_SITE, open_stream, simulate_gnss

    stream = open_stream("car", rate_hz=100.0, seed=seed, site=DEFAULT_SITE)
    block = stream.next_block(30_000)
    est = make_estimator("ins", declination_rad=stream.earth_field.declination_rad, **params)
    feed = GnssFixFeed(est, simulate_gnss(block, rate_hz=5.0, seed=1000 + seed, lever_arm_m=MAST_M))
    q = block.truth_q_wxyz
    true_yaw = Rotation.from_quat(np.column_stack([q[:, 1:], q[:, :1]])).as_euler("ZYX")[:, 0]
    beyond, known = 0, 0
    for i in range(len(block.t_s)):
        feed.offer_until(block.t_s[i])
        view = est.step(make_sample(block.t_s[i], block.gyro_rad_s[i], block.accel_m_s2[i], block.mag_ut[i]))
        if block.t_s[i] < 120.0 or i % every:
            continue
        e = view.snapshot()
        if e.yaw_rad is None or e.sigma_rpy_rad[2] >= est.params.heading_unknown_sigma_rad:
            continue
        known += 1
        err = (e.heading_true_rad - true_yaw[i] + math.pi) % (2.0 * math.pi) - math.pi
        beyond += abs(err) > 3.0 * e.sigma_rpy_rad[2]
    assert known > 0.9 * 18_000 / every
    return beyond / known


@pytest.mark.parametrize("seed", [2])
def test_a_car_told_no_arm_publishes_a_heading_its_sigma_covers(seed):
    # told no arm, told it may be the lever-arm check's prior (2 m) from the IMU
    # (the arm fused as exact, the default, puts ≥ 5 % of them beyond 3σ: the mutations lever-arm-consider-fused and
    # lever-arm-consider-velocity, which tools/mutation_check.py runs, not a second run of the car here)
    honest = car_told_none(seed, {"lever_arm_sigma_m": PRIOR_SIGMA_M})
    assert honest <= 0.01, f"{100 * honest:.2f} % beyond 3σ"
