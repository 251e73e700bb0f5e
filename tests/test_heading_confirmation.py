"""ins's heading confirmation alone (estimator/heading_confirmation.py, HeadingConfirmation), built without a filter:
the alignment to the first valid GNSS yaw, the confirmation by an agreeing GNSS yaw, the published σ's floor until
then. The expected values are the rules written out by hand (the gate: |Δψ|² ≤ 3²·(σ²_filter + σ²_GNSS); the floor:
√(σ²_GNSS + Δψ²))."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ahrsd.estimator.heading_confirmation import HeadingConfirmation

DEG = math.pi / 180.0


def _confirmation(calibration_deg: float = 10.0, mag_enabled: bool = True, checks_run: bool = True):
    c = HeadingConfirmation(align_to_gnss_yaw=True, mag_enabled=mag_enabled, checks_run=checks_run,
                            heading_confirm_sigma_rad=5.0 * DEG, bias_confirm_sigma_rad=10.0 * DEG, gate_sigma=3.0,
                            calibration_sigma_rad=calibration_deg * DEG, trusted_sigma_rad=3.0 * DEG)
    c.start_biases(np.array([0.01, 0.0, 0.0]), np.array([0.0, 0.1, 0.0]))
    return c


def test_an_untrusted_calibration_is_aligned_once_to_the_first_valid_gnss_yaw():
    c = _confirmation()
    assert not c.alignment_due(0.0, 1.0, (4 * DEG) ** 2, False)       # the bank not yet valid
    assert c.alignment_due(0.0, 1.0, (4 * DEG) ** 2, True)
    c.keep_confirmed_biases(np.array([0.5, 0.5, 0.5]), np.array([1.0, 1.0, 1.0]))
    c.aligned()
    assert np.array_equal(c.confirmed_gyro_bias, [0.01, 0.0, 0.0])    # back to the start-up biases
    assert np.array_equal(c.confirmed_accel_bias, [0.0, 0.1, 0.0])
    assert not c.alignment_due(0.0, 1.0, (4 * DEG) ** 2, True)       # once
    assert not _confirmation(calibration_deg=1.0).alignment_due(0.0, 1.0, (4 * DEG) ** 2, True)   # trusted


def test_without_a_magnetometer_only_a_yaw_outside_the_banks_3_sigma_is_aligned():
    c = _confirmation(mag_enabled=False)
    var = (5 * DEG) ** 2
    assert not c.alignment_due(0.0, 14.9 * DEG, var, True)            # inside 3σ = 15°: kept
    assert c.alignment_due(0.0, 15.1 * DEG, var, True)
    assert c.first_gnss_yaw_keeps_yaw(True)
    c.gnss_yaw_seen(True)
    assert not c.alignment_due(0.0, 15.1 * DEG, var, True)            # only at the first valid one
    assert not c.first_gnss_yaw_keeps_yaw(True)


def test_an_agreeing_gnss_yaw_confirms_a_disagreeing_one_widens():
    c = _confirmation()
    yaw_var = (2 * DEG) ** 2
    # 3²·(2² + 4²) = 180 (°²): 13° is inside, 13.5° outside
    assert c.confirm(0.0, 13.5 * DEG, (4 * DEG) ** 2, yaw_var)       # disagrees and wider: the variance is raised
    assert not c.confirm(0.0, 20 * DEG, (1 * DEG) ** 2, yaw_var)      # disagrees, narrower: left alone
    assert not (c.heading_confirmed or c.bias_heading_confirmed)
    assert c.confirm(0.0, 13.0 * DEG, (6 * DEG) ** 2, yaw_var)        # agrees, but 6° is no 5° heading confirmation
    assert c.bias_heading_confirmed and not c.heading_confirmed
    assert not c.confirm(0.0, 13.0 * DEG, (4 * DEG) ** 2, yaw_var)
    assert c.heading_confirmed
    c.magnetometer_rejected()
    assert not (c.heading_confirmed or c.bias_heading_confirmed or c.sigma_confirmed)


def test_after_the_alignment_the_looser_gnss_yaw_confirms():
    c = _confirmation()
    c.aligned()
    assert not c.confirm(0.0, 1.0 * DEG, (8 * DEG) ** 2, (2 * DEG) ** 2)
    assert c.heading_confirmed


def test_the_published_floor_until_a_5_degree_gnss_yaw_agrees():
    c = _confirmation()
    assert c.unconfirmed_sigma_rad == math.pi                           # no GNSS yaw yet
    floor = c.unconfirmed_yaw_sigma(0.0, 10 * DEG, (4 * DEG) ** 2)
    assert floor == pytest.approx(math.hypot(10.0, 4.0) * DEG, rel=1e-12)
    c.aligned()
    c.confirm(0.0, 1.0 * DEG, (8 * DEG) ** 2, (2 * DEG) ** 2)          # confirmed by the looser one ...
    c.update_sigma_confirmation(0.0, 1.0 * DEG, (8 * DEG) ** 2, True, (2 * DEG) ** 2)
    assert not c.sigma_confirmed                                       # ... but the floor stays
    c.update_sigma_confirmation(0.0, 1.0 * DEG, (4 * DEG) ** 2, True, (2 * DEG) ** 2)
    assert c.sigma_confirmed and math.isnan(c.unconfirmed_yaw_sigma(0.0, 1.0 * DEG, (4 * DEG) ** 2))
    assert math.isnan(_confirmation(calibration_deg=1.0).unconfirmed_yaw_sigma(0.0, 1.0, 1.0))    # trusted
    assert math.isnan(_confirmation(checks_run=False).unconfirmed_sigma_rad)


def test_the_accelerometer_bias_waits_for_a_confirmed_heading():
    c = _confirmation()
    assert c.bias_learning_held(True, False)
    assert not c.bias_learning_held(False, False)
    assert not _confirmation(calibration_deg=1.0).bias_learning_held(True, False)
    assert _confirmation(calibration_deg=1.0).bias_learning_held(True, True)   # a trusted one rejected
    c.confirm(0.0, 1.0 * DEG, (8 * DEG) ** 2, (2 * DEG) ** 2)
    assert not c.bias_learning_held(True, False)
