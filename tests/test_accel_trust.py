"""The accelerometer bias a calibration leaves reaches mekf's published tilt σ the same way in the daemon (at start
and after every calibration change, with the calibration's predicted heading error) and in `ahrsd replay
--calibration` (calibration/accel_trust.py): 2 mg with an accelerometer calibration in force, without one the
chip's figure mekf was built with, by default 5 mg (figures from the docstrings' sources: the bench calibration's
residual in calibration/accel_trust.py, the ADIS16405's residual turn-on bias in MekfParams)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ahrsd.calibration.models import AccelModel, Calibration, MagModel
from ahrsd.calibration.store import CalibrationStore
from ahrsd.cli.replay import _told_calibration_sigma
from ahrsd.core.sample import make_sample
from ahrsd.daemon.config import EndpointConfig, EstimatorConfig
from ahrsd.estimator.mekf import Mekf
from service_rig import start_service_on, stop_service

G = 9.80665
CALIBRATED_M_S2 = 2e-3 * G
CHIP_M_S2 = 5e-3 * G


def _with_accel() -> Calibration:
    accel = AccelModel(np.array([0.05, -0.02, 0.1]), np.diag([1.002, 0.998, 1.001]))
    return Calibration.identity().with_sensor("accel", accel, method="test")


HEADING_SIGMA_RAD = math.radians(5.0)      # the calibration below: heading 3°, offset 4°, together hypot = 5°


def _with_accel_and_mag() -> Calibration:
    """An accelerometer calibration, and a magnetometer one that predicts its heading error."""
    return _with_accel().with_sensor("mag", MagModel(np.array([1.0, 0.0, 0.0]), np.eye(3)), method="test",
                                     heading_std_deg=3.0, offset_std_deg=4.0)


def _told(svc) -> float:
    est = svc.pipeline.estimator
    assert est.name == "mekf"
    return float(est._buf[0]["par"]["accel_bias_sigma_m_s2"])      # what the kernel publishes its σ with


def _told_heading_sigma_rad(svc) -> float:
    return float(svc.pipeline.estimator.params.mag_calibration_sigma_rad)


def test_the_daemon_tells_mekf_the_accelerometer_bias_and_heading_error_its_calibration_leaves(tmp_path):
    svc, loop = start_service_on((EndpointConfig("udpout:127.0.0.1:9"),), tmp_path, estimator=EstimatorConfig("mekf"))
    try:
        assert _told(svc) == pytest.approx(CHIP_M_S2)
        assert math.isnan(_told_heading_sigma_rad(svc))                # no calibration: its heading error unknown
        svc.apply_calibration(_with_accel_and_mag(), save=True)      # the one path of every calibration change
        assert _told(svc) == pytest.approx(CALIBRATED_M_S2)
        assert _told_heading_sigma_rad(svc) == pytest.approx(HEADING_SIGMA_RAD)
        svc.apply_calibration(Calibration.identity(), save=True)
        assert _told(svc) == pytest.approx(CHIP_M_S2)
        assert math.isnan(_told_heading_sigma_rad(svc))
    finally:
        stop_service(svc, loop)
    CalibrationStore(tmp_path).save(_with_accel_and_mag())
    svc, loop = start_service_on((EndpointConfig("udpout:127.0.0.1:9"),), tmp_path, estimator=EstimatorConfig("mekf"))
    try:
        assert _told(svc) == pytest.approx(CALIBRATED_M_S2)          # read from the state directory at start
        assert _told_heading_sigma_rad(svc) == pytest.approx(HEADING_SIGMA_RAD)
    finally:
        stop_service(svc, loop)


def test_replay_tells_mekf_the_same_and_a_given_figure_wins():
    assert _told_calibration_sigma("mekf", _with_accel(), {})["accel_bias_sigma_m_s2"] == pytest.approx(CALIBRATED_M_S2)
    assert "accel_bias_sigma_m_s2" not in _told_calibration_sigma("mekf", Calibration.identity(), {})
    assert "accel_bias_sigma_m_s2" not in _told_calibration_sigma("ins", _with_accel(), {})   # ins estimates its bias
    given = {"accel_bias_sigma_m_s2": 0.0}
    assert _told_calibration_sigma("mekf", _with_accel(), given)["accel_bias_sigma_m_s2"] == 0.0


def test_the_published_tilt_variance_moves_by_the_told_bias_over_g_squared():
    """Two mekf fed the same level samples, one told 2 mg, one the chip's 5 mg: their published roll variances
    differ by (5² − 2²) mg² / g² (the levelling's tilt b/g per axis), worked here, not by the kernel's formula."""
    a, b = Mekf(), Mekf()
    b.set_accel_bias_sigma(CALIBRATED_M_S2)
    rng = np.random.default_rng(3)
    for i in range(4000):
        gyro = rng.normal(0.0, 1e-3, 3)
        accel = np.array([0.0, 0.0, -G]) + rng.normal(0.0, 0.02, 3)
        mag = np.array([20.0, 2.0, 43.0]) + rng.normal(0.0, 0.1, 3)
        s = make_sample(i / 200.0, gyro, accel, mag)
        ea, eb = a.update(s), b.update(s)
    diff = ea.sigma_rpy_rad[0] ** 2 - eb.sigma_rpy_rad[0] ** 2
    assert diff == pytest.approx((CHIP_M_S2 ** 2 - CALIBRATED_M_S2 ** 2) / G ** 2, rel=0.02)
    with pytest.raises(ValueError):
        a.set_accel_bias_sigma(math.nan)


def test_no_accelerometer_calibration_brings_back_the_figure_mekf_was_built_with():
    """`set_accel_bias_sigma(None)` (a calibration without the accelerometer's) is the chip's figure as this filter
    was built with it, not the default's 5 mg: a filter built with 30 mg, told 2 mg, then None, is at 30 mg again."""
    built_m_s2 = 0.03
    f = Mekf(accel_bias_sigma_m_s2=built_m_s2)
    f.set_accel_bias_sigma(CALIBRATED_M_S2)
    assert float(f._buf[0]["par"]["accel_bias_sigma_m_s2"]) == pytest.approx(CALIBRATED_M_S2)
    f.set_accel_bias_sigma(None)
    assert float(f._buf[0]["par"]["accel_bias_sigma_m_s2"]) == built_m_s2     # what the kernel publishes its σ with
    assert f.params.accel_bias_sigma_m_s2 == built_m_s2
