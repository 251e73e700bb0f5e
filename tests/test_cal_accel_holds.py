"""`ahrsd calibrate accel` on an ordinary bench recording: 24 positions at 100 Hz held 3 s (or 2 s) each,
joined by 1 s slews, with the ADIS16405 error model's injected bias, scale and misalignment. Default options
must use such holds; short ones are refused with what was found and what to do."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from ahrsd.calibration.inertial.accel import DEFAULT_MIN_STILL_S, hold_cost, still_periods, split_by_duration
from ahrsd.core.sample import make_sample
from ahrsd.drivers.recording import RecordingWriter
from ahrsd.simulation import DEFAULT_SITE, SensorErrors, simulate

from support.accel_positions import holds_recording, position_holds
from support.recordings import write_block

RATE_HZ = 100.0
MG = 9.80665e-3


def calibrate(tmp_path, *args):
    from ahrsd.cli.main import main

    return main(["calibrate", "accel", *map(str, args), "--state-dir", str(tmp_path / "state"), "--json"])


@pytest.mark.parametrize("hold_s", [3.0, 2.0])
def test_short_holds_calibrate_with_default_options(tmp_path, capsys, hold_s):
    block, windows, errors = holds_recording(tmp_path / "holds.csv", hold_s)
    rc = calibrate(tmp_path, tmp_path / "holds.csv", "--lat", DEFAULT_SITE.lat_deg, "--alt-m", DEFAULT_SITE.alt_m)
    out = json.loads(capsys.readouterr().out)
    assert rc == 0, out
    assert out["quality"]["positions"] == 24
    bias_error_mg = np.abs(np.array(out["bias_m_s2"]) - errors.accel_bias_m_s2) / MG
    assert np.all(bias_error_mg <= 2.0), bias_error_mg
    # Independently of the fit's own residual: the calibrated mean of the middle of each truth hold has |f| = g.
    matrix, bias = np.array(out["matrix"]), np.array(out["bias_m_s2"])
    quadratic = np.array(out["quadratic_s2_m"])
    norms = []
    for t0, t1 in windows:
        inside = (block.t_s > t0 + 0.3) & (block.t_s < t1 - 0.3)
        raw = block.accel_m_s2[inside].mean(axis=0)
        norms.append(np.linalg.norm(matrix @ (raw - bias - quadratic * raw * raw)))
    residual_mg = np.sqrt(np.mean((np.array(norms) - DEFAULT_SITE.gravity_m_s2) ** 2)) / MG
    assert residual_mg <= 1.0
    assert out["residual_rms_m_s2"] / MG <= 1.0
    assert out["quality"]["holds"]["hold_s_min"] == pytest.approx(hold_s, abs=0.1)


def test_the_report_says_what_short_holds_cost(tmp_path, capsys):
    from ahrsd.cli.main import main

    holds_recording(tmp_path / "holds.csv", 2.0)
    rc = main(["calibrate", "accel", str(tmp_path / "holds.csv"), "--dry-run", "--state-dir", str(tmp_path)])
    text = capsys.readouterr().out
    assert rc == 0
    assert "holds 2.0–2.0 s" in text and "10-s holds" in text


def test_holds_shorter_than_min_still_are_refused_naming_what_was_found(tmp_path, capsys):
    holds_recording(tmp_path / "short.csv", 1.5)
    rc = calibrate(tmp_path, tmp_path / "short.csv", "--min-still-s", 3.0)
    out = json.loads(capsys.readouterr().out)
    assert rc == 1 and out["saved_to"] is None
    assert out["refused"].startswith("24 still periods, the longest 1.5 s, all shorter than --min-still-s 3:")
    assert "hold each position at least 3 s, or lower --min-still-s" in out["refused"]
    assert not (tmp_path / "state").exists() or not any((tmp_path / "state").iterdir())


def test_a_recording_with_no_still_period_is_refused_saying_so(tmp_path, capsys):
    block = simulate("tumble", 30, rate_hz=RATE_HZ, seed=1)
    write_block(tmp_path / "tumble.csv", block)
    rc = calibrate(tmp_path, tmp_path / "tumble.csv")
    out = json.loads(capsys.readouterr().out)
    assert rc == 1 and out["refused"].startswith("no still period found")
    assert "hold the unit still in each position" in out["refused"]


def test_hold_cost_is_the_white_noise_of_each_mean():
    """σ of a position mean = √3·σ_sample/√n for the simulator's white noise (noise_std), an independent figure."""
    scenario, windows, _ = position_holds(6, hold_s=3.0, slew_s=1.0)
    errors = SensorErrors.adis16405(seed=2)
    block = simulate(scenario, windows[-1][1], rate_hz=RATE_HZ, seed=2, errors=errors)
    used, short = split_by_duration(still_periods(block.accel_m_s2, block.gyro_rad_s, RATE_HZ), DEFAULT_MIN_STILL_S)
    assert len(used) == 6 and not short
    cost = hold_cost(used, short, RATE_HZ)
    sigma = errors.noise_std(RATE_HZ)["accel_m_s2"] * math.sqrt(3)
    n = np.median([p.samples for p in used])
    assert cost["position_noise_m_s2_median"] == pytest.approx(sigma / math.sqrt(n), rel=0.2)
    assert cost["position_noise_m_s2_10s_hold"] == pytest.approx(sigma / math.sqrt(10 * RATE_HZ), rel=0.2)


def test_the_cli_default_is_the_library_default():
    from ahrsd.cli.main import build_parser

    args = build_parser().parse_args(["calibrate", "accel", "x.csv"])
    assert args.min_still_s == DEFAULT_MIN_STILL_S


def test_too_few_long_holds_refusal_also_names_the_short_ones(tmp_path, capsys):
    """4 positions held 3 s, then 20 held 1.5 s: 4 distinct orientations cannot fit 6 parameters, and the
    refusal says that 20 shorter periods were left out and how to use them."""
    long_sc, long_w, _ = position_holds(4, hold_s=3.0, slew_s=1.0)
    short_sc, short_w, _ = position_holds(24, hold_s=1.5, slew_s=1.0)
    a = simulate(long_sc, long_w[-1][1] + 1.0, rate_hz=RATE_HZ, seed=3)
    b_start_s = short_w[4][0] - 1.0    # from the slew into the 5th position on
    b = simulate(short_sc, short_w[-1][1] - b_start_s, rate_hz=RATE_HZ, seed=4, start_s=b_start_s)
    with RecordingWriter(tmp_path / "mixed.csv") as w:
        for block, t0 in ((a, 0.0), (b, a.t_s[-1] + 1 / RATE_HZ - b.t_s[0])):
            for i in range(len(block)):
                w.write(make_sample(t0 + block.t_s[i], block.gyro_rad_s[i], block.accel_m_s2[i], block.mag_ut[i]))
    rc = calibrate(tmp_path, tmp_path / "mixed.csv")
    out = json.loads(capsys.readouterr().out)
    assert rc == 1
    assert out["refused"].startswith("4 distinct orientations cannot determine 6 parameters")
    assert "found 4 still positions" in out["refused"]
    assert "20 more still periods were shorter than --min-still-s 2 (the longest 1.5 s)" in out["refused"]
    assert out["quality"]["holds"]["still_periods_skipped_short"] == 20
