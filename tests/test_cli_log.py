"""`ahrsd log list` / `ahrsd log cut` on logs written by SampleLog: the cut is a plain recording that `replay` and
`calibrate` take as it is, equal to the samples that were logged, and it says which calibration was in force."""

from __future__ import annotations

import datetime as dt
import json

import numpy as np
import pytest

from ahrsd.cli.main import main
from ahrsd.core.sample import make_sample
from ahrsd.drivers.recording import RecordingWriter, read_recording
from ahrsd.drivers.rotating_log import LogLimits
from ahrsd.drivers.sample_log import SampleLog
from ahrsd.simulation import SensorErrors, simulate

from support.accel_positions import position_holds

CAL = {"checksum": "9f2c", "method": "multi-position 12-parameter", "date": "2026-11-30"}
START_UNIX = 1.8e9


@pytest.fixture(scope="module")
def logged(tmp_path_factory):
    """24 positions (3 s holds) at 100 Hz logged as the service would: several files, then the same samples kept
    in memory."""
    d = tmp_path_factory.mktemp("logs")
    scenario, windows, _ = position_holds(24, hold_s=3.0, slew_s=1.0)
    block = simulate(scenario, windows[-1][1], rate_hz=100.0, seed=7, errors=SensorErrors.adis16405(seed=7))
    t0 = 5000.0   # the service's monotonic clock at the first sample
    samples = [make_sample(t0 + block.t_s[i], block.gyro_rad_s[i], block.accel_m_s2[i], block.mag_ut[i], counter=i)
               for i in range(len(block))]
    with SampleLog(d, LogLimits(max_file_bytes=60_000, flush_entries=500), metadata={"calibrated": True,
                   "calibration": CAL}, clock=lambda: START_UNIX, unix_minus_t=lambda: START_UNIX - t0) as log:
        for s in samples:
            log.put(s)
    return d, samples, t0


def run(*argv):
    return main([str(a) for a in argv])


def test_list_shows_each_file_with_its_span_and_calibration(logged, capsys):
    d, samples, _ = logged
    assert run("log", "list", "--dir", d) == 0
    out = capsys.readouterr().out
    assert "calibrated: 9f2c, multi-position 12-parameter" in out and "files," in out
    assert run("log", "list", "--dir", d, "--json") == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert len(rows) >= 3 and sum(r["samples"] for r in rows) == len(samples)
    assert rows[0]["start_utc"] == "2027-01-15T08:00:00Z"   # 1.8e9 s after the epoch


def test_cut_by_iso_time_is_the_logged_window_and_names_the_calibration(logged, tmp_path, capsys):
    d, samples, t0 = logged
    start = dt.datetime.fromtimestamp(START_UNIX + 20.0, dt.timezone.utc).replace(tzinfo=None).isoformat()
    end = dt.datetime.fromtimestamp(START_UNIX + 70.0, dt.timezone.utc).isoformat()
    out_path = tmp_path / "cut.csv"
    assert run("log", "cut", "--dir", d, "--from", start, "--to", end, "--output", out_path) == 0
    assert "calibrated: 9f2c" in capsys.readouterr().err
    rec = read_recording(out_path)
    want = [s for s in samples if t0 + 20.0 <= s.t_s <= t0 + 70.0]
    assert len(rec) == len(want) == 5001
    np.testing.assert_array_equal(rec.accel_m_s2, [s.accel_m_s2 for s in want])
    np.testing.assert_array_equal(rec["counter"], [s.counter for s in want])
    assert "9f2c" in out_path.read_text().splitlines()[1]                  # the comment line
    assert json.loads((tmp_path / "cut.csv.json").read_text())["calibration"] == CAL


def test_a_cut_replays_and_calibrates_as_the_samples_in_memory(logged, tmp_path, capsys):
    d, samples, t0 = logged
    cut = tmp_path / "cut.csv.gz"
    assert run("log", "cut", "--dir", d, "--from", t0, "--to", t0 + 1e6, "--output", cut, "--quiet") == 0
    direct = tmp_path / "direct.csv"
    with RecordingWriter(direct, extra_columns=("temp_c", "supply_v", "flags", "diag_stat", "counter")) as w:
        for s in samples:
            w.write(s)
    results = []
    for rec in (cut, direct):
        capsys.readouterr()
        assert run("calibrate", "accel", rec, "--json", "--dry-run", "--state-dir", tmp_path / "state") == 0
        results.append(json.loads(capsys.readouterr().out))
    assert results[0]["quality"]["positions"] == 24
    np.testing.assert_array_equal(results[0]["bias_m_s2"], results[1]["bias_m_s2"])
    assert run("replay", cut, "--output", tmp_path / "att.csv", "--quiet") == 0
    assert run("replay", direct, "--output", tmp_path / "att_direct.csv", "--quiet") == 0
    assert (tmp_path / "att.csv").read_text() == (tmp_path / "att_direct.csv").read_text()


def test_cut_errors_say_what_was_seen(logged, tmp_path, capsys):
    d, _, _ = logged
    assert run("log", "cut", "--dir", d, "--from", "1", "--to", "2", "--output", tmp_path / "x.csv") == 1
    assert "no logged samples between 1 and 2" in capsys.readouterr().err
    assert run("log", "cut", "--dir", d, "--from", "yesterday", "--to", "2", "--output", tmp_path / "x.csv") == 1
    assert "expected ISO-8601" in capsys.readouterr().err
    assert run("log", "list", "--dir", tmp_path / "none") == 1
    assert "no such log directory" in capsys.readouterr().err
    assert not (tmp_path / "x.csv").exists()


def test_a_window_across_a_calibration_change_is_refused(tmp_path, capsys):
    with SampleLog(tmp_path, metadata={"calibrated": True, "calibration": {"checksum": "aaaa"}}) as log:
        for k in range(100):
            log.put(make_sample(k * 0.01, [0, 0, 0], [0, 0, -9.8], [20, 0, 40]))
        log.set_metadata(calibration={"checksum": "bbbb"})
        for k in range(100, 200):
            log.put(make_sample(k * 0.01, [0, 0, 0], [0, 0, -9.8], [20, 0, 40]))
    assert run("log", "cut", "--dir", tmp_path, "--from", 0, "--to", 2, "--output", tmp_path / "x.csv") == 1
    err = capsys.readouterr().err
    assert "more than one calibration" in err and "aaaa" in err and "bbbb" in err
    assert run("log", "cut", "--dir", tmp_path, "--from", 1.2, "--to", 2, "--output", tmp_path / "y.csv") == 0
    assert len(read_recording(tmp_path / "y.csv")) == 80


def test_samples_from_the_driver_logged_cut_and_replayed_match_the_samples_in_memory(tmp_path):
    """The chain the service will run: the ADIS16405 driver on the simulated chip → SampleLog; then `log cut` and
    `replay` on the cut agree with the estimator run over the very samples that were logged."""
    from ahrsd.drivers.adis16405 import Adis16405
    from ahrsd.drivers.simulated import SimulatedAdis16405
    from ahrsd.estimator import make_estimator
    from ahrsd.estimator.replay import replay_attitude

    imu = Adis16405(SimulatedAdis16405("level-turns", clock=None))
    imu.start()
    samples = [imu.read_sample() for _ in range(int(20 * imu.sample_rate_hz))]
    imu.close()
    with SampleLog(tmp_path / "logs", LogLimits(max_file_bytes=100_000, flush_entries=1000)) as log:
        for s in samples:
            log.put(s)
    assert log.files_opened >= 3 and log.dropped == 0
    t0 = samples[0].t_s
    cut = tmp_path / "cut.csv.gz"
    assert run("log", "cut", "--dir", tmp_path / "logs", "--from", t0 + 5, "--to", t0 + 15, "--output", cut, "-q") == 0
    assert run("replay", cut, "--output", tmp_path / "att.csv", "--quiet") == 0
    window = [s for s in samples if t0 + 5 <= s.t_s <= t0 + 15]
    want = np.vstack(list(replay_attitude(make_estimator("mekf"), window)))
    got = np.loadtxt(tmp_path / "att.csv", delimiter=",", skiprows=1)
    assert got.shape[0] == len(window) == want.shape[0]
    np.testing.assert_allclose(got[:, 0], want[:, 0], atol=1e-6)        # t_s
    np.testing.assert_allclose(got[:, 5:8], want[:, 5:8], atol=2e-6)    # roll, pitch, yaw (deg)


def test_a_log_killed_within_its_opening_is_skipped_by_the_cut(tmp_path, capsys):
    with SampleLog(tmp_path) as log:
        for k in range(100):
            log.put(make_sample(k * 0.01, [0, 0, 0], [0, 0, -9.8], [20, 0, 40]))
    (tmp_path / "imu-29990101T000000.000000Z.csv.gz").write_bytes(b"\x1f\x8b\x08\x00")   # torn in its header
    assert run("log", "cut", "--dir", tmp_path, "--from", 0, "--to", 1e9, "--output", tmp_path / "x.csv") == 0
    assert len(read_recording(tmp_path / "x.csv")) == 100


def test_list_shows_the_mavlink_traffic_logs_beside_the_samples(tmp_path, capsys):
    """The README's `log list` lists the MAVLink .tlog too (session 23's walk: it showed only the samples)."""
    from ahrsd.drivers.tlog import TlogLog

    ticks = iter(range(10**6))     # the wall clock: one second later at every reading
    clock = lambda: START_UNIX + next(ticks)   # noqa: E731
    with SampleLog(tmp_path, clock=clock, unix_minus_t=lambda: START_UNIX - 10.0) as log:
        for i in range(50):
            log.put(make_sample(10.0 + i / 100, [0.0] * 3, [0.0, 0.0, -9.8], [20.0, 0.0, 40.0], counter=i))
    with TlogLog(tmp_path, clock=clock) as tlog:
        for i in range(7):
            tlog.put((START_UNIX + i, b"\xfd" + bytes(11)))
    (sidecar,) = [json.loads(p.read_text()) for p in tmp_path.glob("mavlink-*.tlog.json")]
    opened, closed = (sidecar[k][:19] + "Z" for k in ("opened_utc", "closed_utc"))
    assert opened < closed and opened.startswith("2027-01-15T08:00:")
    assert run("log", "list", "--dir", tmp_path) == 0
    lines = capsys.readouterr().out.splitlines()
    tlog_lines = [x for x in lines if x.startswith("mavlink-") and x.split()[0].endswith(".tlog")]
    assert len(tlog_lines) == 1, lines
    assert f"{opened} → {closed}" in tlog_lines[0] and "7 MAVLink messages" in tlog_lines[0]
    assert lines[-1].startswith("2 files (1 of MAVLink traffic)"), lines[-1]
    assert run("log", "list", "--dir", tmp_path, "--json") == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    (row,) = [r for r in rows if r["kind"] == "tlog"]
    assert (row["messages"], row["start_utc"], row["end_utc"], row["closed"]) == (7, opened, closed, True)
