"""`ahrsd calibrate gyro|mag` refusals say what was found and what to do (as `calibrate accel` does): a turning
recording given to the bias-only gyro fit, a rate-table run with too few steady segments, and a magnetometer
recording too short to fit. The figures in the messages are those the recordings were built with."""

from __future__ import annotations

import json
import math

import numpy as np

from ahrsd.cli.main import main
from ahrsd.core.sample import make_sample
from ahrsd.drivers.recording import RecordingWriter


def write(path, n, rate_hz=100.0, gyro_rad_s=(0.0, 0.0, 0.0), mag_ut=(20.0, 0.0, 40.0)):
    rng = np.random.default_rng(5)
    with RecordingWriter(path) as w:
        for k in range(n):
            w.write(make_sample(k / rate_hz, np.asarray(gyro_rad_s) + rng.normal(0, 1e-4, 3),
                                [0.0, 0.0, -9.80665] + rng.normal(0, 1e-3, 3), np.asarray(mag_ut) + rng.normal(0, 0.05, 3)))
    return path


def refusal(capsys, *argv) -> str:
    capsys.readouterr()
    assert main(["calibrate", *map(str, argv), "--json", "--dry-run"]) == 1
    out = json.loads(capsys.readouterr().out)
    return out.get("refused") or out["error"]


def test_gyro_bias_only_on_a_turning_unit_names_the_rate_and_says_to_record_it_at_rest(tmp_path, capsys):
    rec = write(tmp_path / "turning.csv", 1000, gyro_rad_s=(0.0, 0.0, math.radians(10.0)))  # 10 °/s about z
    text = refusal(capsys, "gyro", rec, "--bias-only", "--state-dir", tmp_path)
    assert "mean rate 10.00 °/s over " in text and "2.86 °/s a bias can be" in text
    assert "Record it at rest" in text


def test_gyro_rate_table_with_one_steady_segment_says_what_to_record(tmp_path, capsys):
    rec = write(tmp_path / "still.csv", 1000)             # one still stretch: one segment, no turn
    text = refusal(capsys, "gyro", rec, "--table-rate-deg-s", 30, "--state-dir", tmp_path)
    assert text.startswith("only 1 steady segments") and "turned: none" in text
    assert "a constant-rate turn about each of the three sensor axes" in text


def test_mag_on_a_too_short_recording_gives_the_count_and_says_record_longer(tmp_path, capsys):
    rec = write(tmp_path / "short.csv", 20)
    text = refusal(capsys, "mag", rec, "--lat", 36.42, "--lon", 54.98, "--state-dir", tmp_path)
    assert "too few samples: 20 usable, need at least 30" in text and "record longer while turning" in text


def test_every_calibrate_subcommand_carries_plot_and_json():
    """calibrate.run reads args.plot and args.json plainly (no getattr): every subcommand's parser defines them."""
    import argparse

    from ahrsd.cli import calibrate

    parser = argparse.ArgumentParser()
    calibrate.register(parser.add_subparsers())
    for sensor in ("allan", "accel", "gyro", "mag"):
        args = parser.parse_args(["calibrate", sensor, "rec.csv"])
        assert (args.plot, args.json) == (None, False), sensor
