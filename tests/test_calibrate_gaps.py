"""Gaps in a recording (calibration/recording_gaps.py) and the one check `ahrsd calibrate` makes of them: counted
from the sample counter or the time stamps (the truth is the block the test dropped), refused by a fit that relates
samples across time (the rate-table reference from the truth attitude), reported by a fit that averages
(--table-rate-deg-s, Allan), and carried by --json."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ahrsd.calibration.recording_gaps import MAX_GAP_INTEGRATING_S, GapCounter, find_gaps
from ahrsd.cli import main as cli
from ahrsd.core.sample import make_sample
from ahrsd.drivers.recording import TRUTH_COLUMNS, RecordingWriter
from ahrsd.simulation import SensorErrors, simulate

RATE_HZ = 20.0
DROPPED = slice(2000, 2020)     # 1 s in the middle of the run: 20 samples, well above MAX_GAP_INTEGRATING_S


def counter_with_a_dropped_block(n=1000, start=100, length=50):
    kept = np.r_[0:start, start + length:n]
    return kept / 819.2, kept.astype(float)


def test_a_dropped_block_is_counted_from_the_counter_and_from_the_time_stamps():
    t_s, counter = counter_with_a_dropped_block()
    for gaps in (find_gaps(t_s, counter), find_gaps(t_s)):
        assert (gaps.missing_samples, gaps.gaps, gaps.longest_gap_samples) == (50, 1, 50)
        assert gaps.longest_gap_s == pytest.approx(50 / 819.2)
        assert gaps.missing_share == pytest.approx(50 / 1000)
    assert find_gaps(t_s, counter).counted_from == "counter" and find_gaps(t_s).counted_from == "t_s"


def test_single_lost_samples_are_gaps_and_a_step_back_is_none():
    """By hand: samples 0..99 at 819.2 SPS without 10, 20 and 21 (a step of k counts or periods is k − 1 lost), and
    a restarted counter (a step back) that loses nothing."""
    kept = np.array([k for k in range(100) if k not in (10, 20, 21)])
    t_s = kept / 819.2
    for gaps in (find_gaps(t_s, kept.astype(float)), find_gaps(t_s)):
        assert (gaps.missing_samples, gaps.gaps, gaps.longest_gap_samples) == (3, 2, 2), gaps.counted_from
    restarted = np.r_[np.arange(50.0), np.arange(50.0)]
    assert find_gaps(np.arange(100) / 819.2, restarted).missing_samples == 0


def test_a_counter_that_never_advances_gives_way_to_the_time_stamps():
    t_s, _ = counter_with_a_dropped_block()
    gaps = find_gaps(t_s, np.zeros(len(t_s)))
    assert gaps.counted_from == "t_s" and gaps.missing_samples == 50


def test_chunks_count_the_same_gaps_as_the_whole_recording_also_across_a_chunk_boundary():
    t_s, counter = counter_with_a_dropped_block()
    for source in (counter, None):
        counted = GapCounter()
        for cut in (np.r_[0:100], np.r_[100:400], np.r_[400:len(t_s)]):     # the gap lies between chunks 1 and 2
            counted.add(t_s[cut], None if source is None else source[cut])
        assert counted.result() == find_gaps(t_s, source)
        assert counted.result().missing_samples == 50


def write_table(path, drop=None):
    """The simulated rate table at 20 Hz (truth columns and the sample counter), without the samples `drop`."""
    block = simulate("rate-table", 430, rate_hz=RATE_HZ, seed=3, errors=SensorErrors.adis16405(seed=3))
    keep = np.ones(len(block), bool)
    if drop is not None:
        keep[drop] = False
    with RecordingWriter(path, extra_columns=("counter",) + TRUTH_COLUMNS) as w:
        for i in np.flatnonzero(keep):
            w.write(make_sample(i / RATE_HZ, block.gyro_rad_s[i], block.accel_m_s2[i], block.mag_ut[i], counter=int(i)),
                    truth_q_wxyz=block.truth_q_wxyz[i])
    return path


@pytest.fixture(scope="module")
def tables(tmp_path_factory):
    d = tmp_path_factory.mktemp("tables")
    return write_table(d / "clean.csv"), write_table(d / "gappy.csv", DROPPED)


def calibrate_json(capsys, *argv):
    code = cli.main(["calibrate", *map(str, argv), "--json", "--dry-run"])
    return code, json.loads(capsys.readouterr().out)


def test_the_truth_referenced_rate_table_refuses_a_recording_with_a_long_gap(tables, tmp_path, capsys):
    assert (DROPPED.stop - DROPPED.start) / RATE_HZ > MAX_GAP_INTEGRATING_S
    clean, gappy = tables
    code, out = calibrate_json(capsys, "gyro", gappy, "--state-dir", tmp_path)
    assert code == 1
    assert "gaps" in out["refused"] and "20 samples missing" in out["refused"]
    assert out["gaps"]["missing_samples"] == 20 and out["gaps"]["longest_gap_samples"] == 20
    assert out["gaps"]["gaps"] == 1 and out["gaps"]["counted_from"] == "counter"
    assert out["matrix"] == np.eye(3).tolist() and "rejected_model" in out["quality"]   # nothing usable
    code, out = calibrate_json(capsys, "gyro", clean, "--state-dir", tmp_path)
    assert code == 0 and out["refused"] is None
    assert out["gaps"]["missing_samples"] == 0 and out["gaps"]["gaps"] == 0


def test_a_fit_that_averages_reports_the_gaps_and_fits(tables, tmp_path, capsys):
    _, gappy = tables
    code, out = calibrate_json(capsys, "gyro", gappy, "--table-rate-deg-s", 90, "--state-dir", tmp_path)
    assert code == 0 and out["refused"] is None
    assert out["gaps"]["missing_samples"] == 20
    code = cli.main(["calibrate", "gyro", str(gappy), "--table-rate-deg-s", "90", "--dry-run", "--state-dir",
                     str(tmp_path)])
    assert code == 0
    assert "gaps: 20 samples missing (0.2%) in 1 gaps, the longest 20 samples (1 s" in capsys.readouterr().out


def test_still_fits_report_the_gaps_and_the_estimator_run_refuses_them(tmp_path, capsys):
    """allan (streamed) and --bias-only average; --estimator-bias runs the estimator across the 0.35 s gap."""
    path = tmp_path / "still.csv"
    block = simulate("static", 120, rate_hz=RATE_HZ, seed=3, errors=SensorErrors.adis16405(seed=3))
    with RecordingWriter(path, extra_columns=("counter",)) as w:
        for i in np.r_[0:1000, 1007:len(block)]:
            w.write(make_sample(i / RATE_HZ, block.gyro_rad_s[i], block.accel_m_s2[i], block.mag_ut[i], counter=int(i)))
    code, out = calibrate_json(capsys, "allan", path, "--state-dir", tmp_path)
    assert code == 0
    assert (out["gaps"]["missing_samples"], out["gaps"]["longest_gap_samples"]) == (7, 7)
    code, out = calibrate_json(capsys, "gyro", "--bias-only", path, "--state-dir", tmp_path)
    assert code == 0 and out["gaps"]["missing_samples"] == 7
    code, out = calibrate_json(capsys, "gyro", "--bias-only", "--estimator-bias", path, "--state-dir", tmp_path)
    assert code == 1 and "the estimator run of --estimator-bias" in out["refused"]


def test_backstepping_refuses_a_boat_recording_with_a_long_gap_and_fits_the_whole_one(tmp_path, capsys):
    from ahrsd.simulation import DEFAULT_SITE as SITE

    blk = simulate("level-turns", 120, rate_hz=RATE_HZ, seed=3, errors=SensorErrors.adis16405(seed=3))
    site = ["--lat", SITE.lat_deg, "--lon", SITE.lon_deg, "--alt-m", SITE.alt_m, "--date", SITE.date.isoformat()]
    for name, kept in (("whole", np.arange(len(blk))), ("gappy", np.r_[0:1000, 1020:len(blk)])):
        path = tmp_path / f"{name}.csv"
        with RecordingWriter(path, extra_columns=("counter",)) as w:
            for i in kept:
                w.write(make_sample(blk.t_s[i], blk.gyro_rad_s[i], blk.accel_m_s2[i], blk.mag_ut[i], counter=int(i)))
        code, out = calibrate_json(capsys, "mag", "--method", "backstepping", path, *site, "--state-dir", tmp_path)
        assert out["gaps"]["missing_samples"] == len(blk) - len(kept)
        if name == "whole":
            assert code == 0 and out["refused"] is None
        else:
            assert code == 1 and "gap longer than 0.05 s" in out["refused"]
            assert out["hard_iron_ut"] == [0.0, 0.0, 0.0] and "rejected_model" in out["quality"]
