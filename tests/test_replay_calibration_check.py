"""`ahrsd replay` (mekf, no GNSS) of a recording whose calibration states its heading error: the summary names the
circle check's verdict as the daemon does (estimator/field_circle.py, daemon/heading_status.py) and the output marks
the samples where it finds the calibration wrong (mag_cal_check = 2).

The recording is the simulated plane (bench/vehicle_accuracy.simulate_vehicle: it turns within its first 30 s) with
the calibrated field left 6 µT off horizontally (bench/unaided_sigma.wrong_calibration_field: a calibration whose
hard iron is wrong by that much); the truth (the iron given, the heading error against the simulator's attitude)
never comes from the code under test."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from bench.unaided_sigma import errors_rph, wrong_calibration_field
from bench.vehicle_accuracy import simulate_vehicle
from ahrsd.cli.main import main
from ahrsd.cli.replay import FIELD_CIRCLE_OUTPUT_COLUMNS, OUTPUT_HEADER
from ahrsd.drivers.recording import RECORDING_HEADER

SEED = 12
HARD_IRON_ERROR_UT = 6.0                 # vs the default site's H ≈ 20 µT: a heading error of up to ~17°
CLAIMED_SIGMA_RAD = math.radians(0.5)    # what a good calibration states


def _recording(tmp_path, seconds, error_ut=HARD_IRON_ERROR_UT):
    run = simulate_vehicle("plane", seconds, SEED, None)
    mag = wrong_calibration_field(run.mag_ut, error_ut, math.radians(30.0), 0.0)
    path = tmp_path / f"plane{seconds:.0f}.csv"
    np.savetxt(path, np.column_stack([run.t_s, run.gyro_rad_s, run.accel_m_s2, mag]), delimiter=",",
               header=RECORDING_HEADER, comments="", fmt="%.10g")
    return path, run


def _replay(capsys, path, out, sigma_rad):
    capsys.readouterr()
    args = ["replay", str(path), "-o", str(out)]
    if sigma_rad is not None:   # as --calibration tells it from the file's figure (calibration/heading_trust.py)
        args += ["--set", f"mag_calibration_sigma_rad={sigma_rad!r}"]
    assert main(args) == 0
    err = capsys.readouterr().err
    lines = out.read_text().splitlines()
    return err, lines[0].split(","), np.loadtxt(out, delimiter=",", skiprows=1)


def test_a_wrong_hard_iron_is_named_with_when_and_how_much(tmp_path, capsys):
    path, run = _recording(tmp_path, 60.0)
    err, cols, data = _replay(capsys, path, tmp_path / "out.csv", CLAIMED_SIGMA_RAD)
    assert cols == OUTPUT_HEADER.split(",") + list(FIELD_CIRCLE_OUTPUT_COLUMNS)
    verdict = data[:, cols.index("mag_cal_check")].astype(int)
    centre = data[:, cols.index("mag_field_centre_ut")]
    wrong = verdict == 2
    assert wrong.any(), np.unique(verdict)
    first = int(np.argmax(wrong))
    # the truth: the calibration is wrong by the iron given, and its heading error is far beyond what it states
    heading_err = errors_rph(data[:, 1:5], run.truth_q_wxyz, run.declination_rad)[:, 2]
    assert np.max(np.abs(heading_err[:first])) > 3.0 * CLAIMED_SIGMA_RAD
    assert centre[wrong] == pytest.approx(HARD_IRON_ERROR_UT, abs=1.0)
    # once flagged, the σ covers the error (the verdict enters the published σ)
    sigma = np.radians(data[first:, cols.index("sigma_yaw_deg")])
    assert np.mean(np.abs(heading_err[first:]) <= 3.0 * sigma) >= 0.99
    # the summary names it as the daemon does, when (the first marked sample) and by how much (the column's)
    m = re.search(r"WARNING: magnetometer field off-centre by ([0-9.]+) µT in turns: calibration wrong or iron "
                  r"changed \(found at ([0-9.]+) s", err)
    assert m, err
    assert float(m.group(1)) == pytest.approx(centre[first], abs=0.051)
    assert float(m.group(2)) == pytest.approx(data[first, 0], abs=0.051)
    # mekf then removes the hard iron it learned from the turns (field_circle_correction.py): marked 3 once the
    # corrected field is consistent, and the summary says so from the first such sample
    corrected = verdict == 3
    assert corrected.any() and int(np.argmax(corrected)) > first
    m = re.search(r"then magnetometer field off-centre by ([0-9.]+) µT in turns: learned correction applied, "
                  r"recalibrate to confirm \(consistent with it from ([0-9.]+) s", err)
    assert m, err
    assert float(m.group(1)) == pytest.approx(HARD_IRON_ERROR_UT, abs=1.0)
    assert float(m.group(2)) == pytest.approx(data[int(np.argmax(corrected)), 0], abs=0.051)


def test_a_calibration_that_states_the_error_it_leaves_is_consistent(tmp_path, capsys):
    """The same iron under a calibration stating 20°: the circle's heading error (~12° RMS) is within it, and the
    truth agrees (the error stays within 3 × 20°). A threshold of the wrong sign would call it wrong."""
    stated = math.radians(20.0)
    path, run = _recording(tmp_path, 60.0)
    err, cols, data = _replay(capsys, path, tmp_path / "out.csv", stated)
    heading_err = errors_rph(data[:, 1:5], run.truth_q_wxyz, run.declination_rad)[:, 2]
    ok = np.isfinite(heading_err)
    assert np.max(np.abs(heading_err[ok])) < 3.0 * stated
    verdict = data[:, cols.index("mag_cal_check")].astype(int)
    assert not np.any(verdict == 2) and np.any(verdict == 1), np.unique(verdict)
    assert "checked, consistent" in err and "WARNING" not in err, err


def test_a_right_calibration_is_consistent_and_without_turns_not_judged(tmp_path, capsys):
    path, _ = _recording(tmp_path, 60.0, error_ut=0.0)
    err, cols, data = _replay(capsys, path, tmp_path / "right.csv", CLAIMED_SIGMA_RAD)
    assert not np.any(data[:, cols.index("mag_cal_check")] == 2)
    assert "checked, consistent" in err and "off-centre" not in err, err
    # the first 20 s: the plane has not yet turned through 270°
    short, _ = _recording(tmp_path, 20.0)
    err, cols, data = _replay(capsys, short, tmp_path / "short.csv", CLAIMED_SIGMA_RAD)
    assert np.all(data[:, cols.index("mag_cal_check")] == 0)
    assert "not judged: the vehicle did not turn enough" in err, err


def test_without_a_stated_calibration_error_the_output_is_unchanged(tmp_path, capsys):
    path, _ = _recording(tmp_path, 20.0)
    err, cols, _ = _replay(capsys, path, tmp_path / "plain.csv", None)
    assert ",".join(cols) == OUTPUT_HEADER
    assert "checked without GNSS" not in err


def test_without_a_calibration_the_heading_is_unknown_as_the_daemon_says(tmp_path, capsys):
    """No --calibration: the magnetometer's calibration is unknown, as the daemon takes an empty state directory
    ("hdg unknown uncal"). The σ column must cover the heading error the wrong iron leaves (truth from the
    simulator: ~12° RMS here once the plane turns), the summary must say why, and roll and pitch keep their own σ. Told it was
    calibrated (0.5°), mekf's σ is small again and nothing is said."""
    path, run = _recording(tmp_path, 60.0)
    err, cols, data = _replay(capsys, path, tmp_path / "none.csv", None)
    heading_err = np.degrees(errors_rph(data[:, 1:5], run.truth_q_wxyz, run.declination_rad)[:, 2])
    sigma_yaw = data[:, cols.index("sigma_yaw_deg")]
    ok = np.isfinite(heading_err)
    assert np.max(np.abs(heading_err[ok])) > 5.0                        # the case is one a small σ would not cover
    assert np.all(np.abs(heading_err[ok]) <= 3.0 * sigma_yaw[ok])
    assert np.median(data[:, cols.index("sigma_roll_deg")]) < 5.0
    assert "heading unknown" in err and "no magnetometer calibration given" in err, err
    err, cols, data = _replay(capsys, path, tmp_path / "told.csv", CLAIMED_SIGMA_RAD)
    assert np.median(data[:, cols.index("sigma_yaw_deg")]) < 5.0 and "heading unknown" not in err, err
