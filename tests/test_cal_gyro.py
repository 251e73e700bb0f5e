"""Gyro calibration (calibration/inertial/gyro.py): rate table (12 parameters) and bias only.

Simulated rate table (the simulator's six mountings × ±90 °/s, 2 turns each, 5 s holds) at 50 Hz. Each
steady segment of T seconds averages the ARW to 5.8e-4/√T rad/s (≈1.3e-4 for the 20 s turns); the in-run
Gauss–Markov bias (σ 1.2e-4 rad/s, Tc 100 s) moves between segments. With ~50 segments, biases are
determined to ~σ_gm/√(segments/4) ≈ 6e-5 rad/s and matrix entries to ~σ/ω_table ≈ 1e-4.
Tolerances: TOL_BIAS = 3e-4 rad/s, TOL_MATRIX = 6e-4 (≥ 4σ).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from ahrsd.calibration.inertial.gyro import (
    body_rates_from_quaternions,
    fit_bias_only,
    fit_rate_table,
    reference_rates_from_accel,
    reference_rates_from_truth,
    steady_segments,
)
from ahrsd.simulation import SensorErrors, open_stream, simulate

RATE_HZ = 50.0
TOL_BIAS = 3e-4
TOL_MATRIX = 6e-4


def run_table(errs: SensorErrors, seed=4):
    block = simulate("rate-table", 430, rate_hz=RATE_HZ, seed=seed, errors=errs)
    segs = steady_segments(block.gyro_rad_s, block.accel_m_s2, RATE_HZ)
    raw = np.array([s.mean_gyro_rad_s for s in segs])
    return block, segs, raw


def test_rate_table_recovers_the_simulated_adis16405():
    errs = SensorErrors.adis16405(seed=4)
    block, segs, raw = run_table(errs)
    assert len(segs) >= 36
    res = fit_rate_table(raw, reference_rates_from_truth(segs, block.truth_gyro_rad_s),
                         weights=[s.stop - s.start for s in segs])
    assert res.ok, res.refused
    assert res.quality["axes_turned"] == ["+x", "+y", "+z", "-x", "-y", "-z"]
    np.testing.assert_allclose(res.model.bias_rad_s, errs.gyro_bias_rad_s, atol=TOL_BIAS)
    np.testing.assert_allclose(res.model.matrix, np.linalg.inv(errs.gyro_matrix), atol=TOL_MATRIX)


def test_thesis_gyro_calibration_figures_as_truth_are_recovered():
    """Worked example, the thesis's gyro calibration result: gains 0.98, 0.96, 0.99; biases (ambiguous digits) read as
    0.01, 0.005, 0.001 rad/s; misalignments of the order of 1e-3 rad (unrecoverable glyphs)."""
    gain = np.array([0.98, 0.96, 0.99])
    bias = np.array([0.01, 0.005, 0.001])
    mis = np.array([[0, -0.002, 0.001], [0.0015, 0, -0.0025], [-0.001, 0.002, 0]])
    errs = SensorErrors.adis16405(seed=5).replace(gyro_bias_rad_s=bias, gyro_scale=gain - 1,
                                                   gyro_misalignment_rad=mis)
    block, segs, raw = run_table(errs, seed=5)
    res = fit_rate_table(raw, reference_rates_from_truth(segs, block.truth_gyro_rad_s),
                         weights=[s.stop - s.start for s in segs])
    assert res.ok, res.refused
    np.testing.assert_allclose(res.model.bias_rad_s, bias, atol=TOL_BIAS)
    np.testing.assert_allclose(res.model.matrix, np.linalg.inv(np.diag(gain) + mis), atol=TOL_MATRIX)
    np.testing.assert_allclose(1 / np.diag(res.model.matrix), gain, atol=2 * TOL_MATRIX)


def test_reference_from_table_rate_and_gravity():
    """Without truth: the table rate magnitude plus the vertical from the (ideal) accelerometer."""
    errs = SensorErrors.adis16405(seed=6).replace(accel_bias_m_s2=np.zeros(3), accel_scale=np.zeros(3),
                                                   accel_misalignment_rad=np.zeros((3, 3)))
    block, segs, raw = run_table(errs, seed=6)
    ref = reference_rates_from_accel(segs, math.radians(90.0))
    truth = reference_rates_from_truth(segs, block.truth_gyro_rad_s)
    np.testing.assert_allclose(ref, truth, atol=2e-3)  # accel noise/in-run bias tilt the vertical slightly
    res = fit_rate_table(raw, ref, weights=[s.stop - s.start for s in segs])
    assert res.ok
    np.testing.assert_allclose(res.model.matrix, np.linalg.inv(errs.gyro_matrix), atol=3e-3)


def test_body_rates_from_truth_quaternions():
    block = simulate("tumble", 20, rate_hz=200.0, seed=1, errors="ideal")
    rates = body_rates_from_quaternions(block.t_s, block.truth_q_wxyz)
    np.testing.assert_allclose(rates[1:-1], block.truth_gyro_rad_s[1:-1], atol=2e-3)


def test_rate_table_refuses_turns_about_one_axis_only():
    rng = np.random.default_rng(0)
    raw = np.vstack([np.zeros((4, 3)), [[0, 0, 1.57]] * 3, [[0, 0, -1.57]] * 3]) + rng.normal(0, 1e-4, (10, 3))
    ref = np.vstack([np.zeros((4, 3)), [[0, 0, 1.5708]] * 3, [[0, 0, -1.5708]] * 3])
    res = fit_rate_table(raw, ref)
    assert not res.ok and "condition number" in res.refused and "+z" in res.refused
    res = fit_rate_table(raw[:2], ref[:2])
    assert not res.ok and "only 2 steady segments" in res.refused


def test_bias_only_from_a_static_recording():
    errs = SensorErrors.adis16405(seed=7)
    block = simulate("static", 120, rate_hz=RATE_HZ, seed=7, errors=errs)
    res = fit_bias_only(block.gyro_rad_s)
    assert res.ok and res.method == "bias-only"
    # 120 s of ARW averages to 5.8e-4/√120 = 5e-5 rad/s; the in-run GM bias adds up to ~σ_gm = 1.2e-4.
    np.testing.assert_allclose(res.model.bias_rad_s, errs.gyro_bias_rad_s, atol=5e-4)
    np.testing.assert_array_equal(res.model.matrix, np.eye(3))
    moving = simulate("level-turns", 30, rate_hz=RATE_HZ, seed=7)
    res = fit_bias_only(moving.gyro_rad_s)
    assert not res.ok and "was the unit still" in res.refused


def test_json_keys():
    res = fit_bias_only(np.zeros((100, 3)) + 0.001)
    d = res.to_json_dict()
    assert d["bias_rad_s"] == pytest.approx([0.001] * 3) and np.asarray(d["matrix"]).shape == (3, 3)
