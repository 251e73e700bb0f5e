"""A calibration's predicted heading error reaches `ins` wherever a calibration is applied (issue 28): at
`ahrsd replay --calibration` (as the daemon does at start) and at a calibration hot swap
(`Ins.set_mag_calibration_sigma`, called by the daemon's calibration swap)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ahrsd.estimator import ins_core as core


def test_a_new_calibration_sigma_replaces_the_one_ins_started_with():
    from ahrsd.estimator.ins import DEFAULT_INS_PARAMS, Ins

    ins = Ins()
    uncal = DEFAULT_INS_PARAMS.mag_uncalibrated_sigma_rad
    assert ins._monitor.calibration_sigma_rad == pytest.approx(uncal)
    ins.set_mag_calibration_sigma(math.radians(0.5))
    assert ins.params.mag_calibration_sigma_rad == pytest.approx(math.radians(0.5))
    assert ins._monitor.calibration_sigma_rad == pytest.approx(math.radians(0.5))
    assert ins._par["mag_bias_var_rad2"] == pytest.approx(math.radians(0.5) ** 2)
    assert ins._par["mag_bias_tau_s"] == pytest.approx(DEFAULT_INS_PARAMS.mag_bias_tau_s)
    ins.set_mag_calibration_sigma(math.nan)           # a calibration whose quality is unknown
    assert ins._monitor.calibration_sigma_rad == pytest.approx(uncal)
    assert ins._par["mag_bias_var_rad2"] == pytest.approx(uncal ** 2)
    assert ins._par["mag_bias_tau_s"] == pytest.approx(DEFAULT_INS_PARAMS.mag_uncalibrated_tau_s)


def _replay_with(tmp_path, monkeypatch, heading_std_deg, extra=()):
    """`ahrsd replay --estimator ins --calibration FILE` on a 3 s simulated recording; the keyword arguments
    make_estimator got."""
    from ahrsd.calibration.models import Calibration, MagModel
    from ahrsd.calibration.store import CalibrationStore
    from ahrsd.cli.main import main
    import ahrsd.estimator as est

    assert main(["record", "--sim", "boat", "--seconds", "3", "-o", str(tmp_path / "r.csv")]) == 0
    cal = Calibration.identity().with_sensor("mag", MagModel(np.array([1.0, 0.0, 0.0]), np.eye(3)), method="test",
                                             heading_std_deg=heading_std_deg, offset_std_deg=0.0)
    path = CalibrationStore(tmp_path / "state").save(cal)
    got = {}
    make = est.make_estimator

    def spy(name, **kwargs):
        got.update(kwargs)
        return make(name, **kwargs)

    monkeypatch.setattr(est, "make_estimator", spy)
    assert main(["replay", str(tmp_path / "r.csv"), "--estimator", "ins", "--calibration", str(path),
                 "-o", str(tmp_path / "o.csv"), *extra]) == 0
    return got


def test_replay_passes_the_calibrations_predicted_heading_error_to_ins(tmp_path, monkeypatch):
    got = _replay_with(tmp_path, monkeypatch, 0.3)
    assert got["mag_calibration_sigma_rad"] == pytest.approx(math.radians(0.3))
