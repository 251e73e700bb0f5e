"""A calibration's predicted heading error reaches `ins` wherever a calibration is applied (issue 28): at
`ahrsd replay --calibration` (as the daemon does at start) and at a calibration hot swap
(`Ins.set_mag_calibration_sigma`, called by the daemon's calibration swap)."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest

from ahrsd.estimator import ins_core as core


def test_a_new_calibration_sigma_replaces_the_one_ins_started_with():
    from ahrsd.estimator.ins import DEFAULT_INS_PARAMS, Ins

    ins = Ins()
    uncal = DEFAULT_INS_PARAMS.mag_uncalibrated_sigma_rad
    assert ins._heading.monitor.calibration_sigma_rad == pytest.approx(uncal)
    ins.set_mag_calibration_sigma(math.radians(0.5))
    assert ins.params.mag_calibration_sigma_rad == pytest.approx(math.radians(0.5))
    assert ins._heading.monitor.calibration_sigma_rad == pytest.approx(math.radians(0.5))
    assert ins._par["mag_bias_var_rad2"] == pytest.approx(math.radians(0.5) ** 2)
    assert ins._par["mag_bias_tau_s"] == pytest.approx(DEFAULT_INS_PARAMS.mag_bias_tau_s)
    ins.set_mag_calibration_sigma(math.nan)           # a calibration whose quality is unknown
    assert ins._heading.monitor.calibration_sigma_rad == pytest.approx(uncal)
    assert ins._par["mag_bias_var_rad2"] == pytest.approx(uncal ** 2)
    assert ins._par["mag_bias_tau_s"] == pytest.approx(DEFAULT_INS_PARAMS.mag_uncalibrated_tau_s)


def _published_yaw_sigma_deg(tmp_path, heading_std_deg) -> np.ndarray:
    """`ahrsd replay --estimator ins --calibration FILE` (no GNSS) on a 3 s simulated recording, the calibration
    predicting `heading_std_deg` of heading error: the published yaw 1σ of every row, degrees."""
    from ahrsd.calibration.models import Calibration, MagModel
    from ahrsd.calibration.store import CalibrationStore
    from ahrsd.cli.main import main

    rec = tmp_path / "r.csv"
    if not rec.exists():
        assert main(["record", "--sim", "boat", "--seconds", "3", "-o", str(rec)]) == 0
    cal = Calibration.identity().with_sensor("mag", MagModel(np.array([1.0, 0.0, 0.0]), np.eye(3)), method="test",
                                             heading_std_deg=heading_std_deg, offset_std_deg=0.0)
    path = CalibrationStore(tmp_path / f"state{heading_std_deg}").save(cal)
    out = tmp_path / f"o{heading_std_deg}.csv"
    assert main(["replay", str(rec), "--estimator", "ins", "--calibration", str(path), "-o", str(out), "--quiet"]) == 0
    with open(out) as f:
        return np.array([float(row["sigma_yaw_deg"]) for row in csv.DictReader(f)])


def test_replay_passes_the_calibrations_predicted_heading_error_to_ins(tmp_path):
    """Without GNSS the calibration is ins's only heading reference and its predicted error is added to the
    published yaw variance (estimator/calibration_heading.py): a calibration predicting 20° publishes no yaw σ below
    20°, one predicting 0.3° ends well below 1° (told nothing, ins would take an unknown calibration's 180°)."""
    wide = _published_yaw_sigma_deg(tmp_path, 20.0)
    assert np.all(wide >= 20.0) and wide[-1] < 25.0
    narrow = _published_yaw_sigma_deg(tmp_path, 0.3)
    assert narrow[-1] < 1.0
