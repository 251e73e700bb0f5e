"""The on-vehicle logs (drivers/sample_log.py, drivers/tlog.py, drivers/rotating_log.py): what is written reads
back as it went in, files rotate by size and age under a total cap, the caller is never blocked (overflow is
dropped and counted), a full or read-only disk stops the log with one warning, and a file cut by a crash
reads up to its last complete line."""

from __future__ import annotations

import errno
import json
import logging
import math
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from ahrsd.core.sample import make_sample
from ahrsd.drivers.recording import iter_samples, read_recording
from ahrsd.drivers.rotating_log import LogLimits
from ahrsd.drivers.sample_log import SampleFile, SampleLog
from ahrsd.drivers.tlog import TlogLog
from support.random_samples import random_samples


def log_files(directory, suffix=".csv.gz"):
    return sorted(p for p in Path(directory).iterdir() if p.name.endswith(suffix))


def assert_same(rec, originals):
    assert len(rec) == len(originals)
    np.testing.assert_array_equal(rec.t_s, [s.t_s for s in originals])
    np.testing.assert_array_equal(rec.gyro_rad_s, [s.gyro_rad_s for s in originals])
    np.testing.assert_array_equal(rec.accel_m_s2, [s.accel_m_s2 for s in originals])
    np.testing.assert_array_equal(rec.mag_ut, [s.mag_ut for s in originals])
    np.testing.assert_array_equal(rec["flags"], [int(s.flags) for s in originals])
    np.testing.assert_array_equal(rec["counter"], [s.counter for s in originals])


def test_samples_read_back_exactly_with_the_calibration_in_the_sidecar(tmp_path):
    data = random_samples(5000)
    cal = {"checksum": "abc123", "method": "multi-position"}
    with SampleLog(tmp_path, metadata={"calibrated": True, "calibration": cal}) as log:
        for s in data:
            assert log.put(s)
    (path,) = log_files(tmp_path)
    assert_same(read_recording(path), data)
    assert [s.counter for s in iter_samples(path)] == list(range(5000))
    side = json.loads(Path(str(path) + ".json").read_text())
    assert side["calibration"] == cal and side["calibrated"] is True and side["closed"] is True
    assert side["entries"] == 5000 and side["t_first_s"] == data[0].t_s and side["t_last_s"] == data[-1].t_s
    assert abs(side["unix_minus_t_s"] - (time.time() - time.monotonic())) < 1.0   # t_s is the monotonic clock


def test_repeated_values_signed_zeros_and_nan_read_back_exactly(tmp_path):
    """The writer remembers the text of values it has formatted (a chip's values recur): −0.0 must stay −0.0
    after a 0.0 was written, and nan stays nan."""
    values = [0.0, -0.0, 0.1, -0.1, 1e-300, -1e300, math.inf, math.nan, 0.30000000000000004]
    data = [make_sample(100.0 + k / 819.2, [values[k % 9], values[(k + 1) % 9], values[(k + 2) % 9]],
                        [values[(k + 3) % 9], 0.0, -0.0], [values[(k + 5) % 9], -0.0, 0.0], temp_c=values[k % 9],
                        counter=k) for k in range(90)]
    with SampleLog(tmp_path) as log:
        for s in data:
            log.put(s)
    (path,) = log_files(tmp_path)
    rec = read_recording(path)
    for got, want in ((rec.gyro_rad_s, [s.gyro_rad_s for s in data]), (rec.accel_m_s2, [s.accel_m_s2 for s in data]),
                      (rec.mag_ut, [s.mag_ut for s in data]), (rec["temp_c"], [s.temp_c for s in data])):
        # bit patterns, so that -0.0 vs 0.0 and nan compare exactly
        np.testing.assert_array_equal(np.asarray(got).view(np.int64), np.asarray(want, dtype=np.float64).view(np.int64))


def test_a_calibration_change_starts_a_new_file_saying_so(tmp_path):
    data = random_samples(200)
    with SampleLog(tmp_path, metadata={"calibration": {"checksum": "old"}}) as log:
        for s in data[:100]:
            log.put(s)
        log.set_metadata(calibration={"checksum": "new"})
        for s in data[100:]:
            log.put(s)
    first, second = log_files(tmp_path)
    assert_same(read_recording(first), data[:100])
    assert_same(read_recording(second), data[100:])
    assert json.loads(Path(str(second) + ".json").read_text())["calibration"] == {"checksum": "new"}


def test_files_rotate_by_size_and_the_oldest_go_beyond_the_total(tmp_path):
    limits = LogLimits(max_file_bytes=40_000, max_total_bytes=200_000, flush_entries=500)
    data = random_samples(40_000)
    with SampleLog(tmp_path, limits) as log:
        for s in data:
            log.put(s)
            if log.queued > 30_000:   # keep within the queue: this test is about rotation, not overflow
                time.sleep(0.01)
        # close() waits a bounded time for its writer (a daemon must stop); at load 16 that was too short for the
        # last 7 500 entries (ci24): wait for them here, by count, so the test is about rotation, not speed
        deadline = time.monotonic() + 300
        while log.written < len(data) - limits.flush_entries and time.monotonic() < deadline:
            time.sleep(0.01)
    files = log_files(tmp_path)
    total = sum(p.stat().st_size + Path(str(p) + ".json").stat().st_size for p in files)
    assert log.files_deleted > 0 and log.dropped == 0
    assert total <= limits.max_total_bytes + limits.max_file_bytes + 20_000
    for p in files[:-1]:
        assert 40_000 <= p.stat().st_size < 40_000 + 20_000    # rotated at the first check past the size
    # what is left is the newest stretch of samples, without a gap
    kept = np.concatenate([read_recording(p)["counter"] for p in files])
    np.testing.assert_array_equal(kept, np.arange(kept[0], 40_000))


def test_files_rotate_by_age(tmp_path):
    now = [1.0e9]
    limits = LogLimits(max_file_age_s=600.0, flush_entries=100)
    with SampleLog(tmp_path, limits, clock=lambda: now[0]) as log:
        for block in range(3):
            for s in random_samples(100, t0=block * 1000.0):
                log.put(s)
            deadline = time.monotonic() + 10
            while log.written < 100 * (block + 1) and time.monotonic() < deadline:
                time.sleep(0.005)
            now[0] += 601.0
    assert len(log_files(tmp_path)) == 3


class _StuckLog(SampleLog):
    """A writer that cannot keep up: blocked until released."""

    release = threading.Event()

    def _write_block(self, file, block):
        self.release.wait(10)
        super()._write_block(file, block)


def test_overflow_is_dropped_and_counted_and_never_blocks_the_caller(tmp_path):
    log = _StuckLog(tmp_path, LogLimits(queue_entries=10))
    data, results = random_samples(100), []
    caller = threading.Thread(target=lambda: results.extend(log.put(s) for s in data))
    caller.start()
    caller.join(5.0)
    blocked = caller.is_alive()
    log.release.set()
    caller.join()
    assert not blocked, "put() waited for the writer"
    # the writer may take the queue's 10 (and then block) a few times while the caller runs: most are dropped
    assert 50 <= log.dropped <= 90 and results.count(False) == log.dropped
    log.close()
    assert log.written + log.dropped == 100
    assert len(read_recording(log_files(tmp_path)[0])) == log.written


class _FullDiskLog(SampleLog):
    """The file's writes go to /dev/full: ENOSPC at the first flush."""

    def _open(self, path):
        super()._open(path).close()
        return SampleFile(open("/dev/full", "wb"))


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full")
def test_a_full_disk_stops_the_log_with_one_warning(tmp_path, caplog):
    caplog.set_level(logging.WARNING)
    log = _FullDiskLog(tmp_path, LogLimits(flush_entries=10))
    for s in random_samples(1000):
        log.put(s)
    log.close()
    assert log.failure is not None and "No space left" in log.failure
    warnings = [r for r in caplog.records if "stopped" in r.getMessage()]
    assert len(warnings) == 1 and "the disk is full" in warnings[0].getMessage()
    assert log.put(random_samples(1)[0]) is False and log.written + log.dropped >= 1000


@pytest.fixture
def small_tmpfs(tmp_path):
    """A 64 kB tmpfs (root only: skipped where mounting is not allowed)."""
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mnt)],
                                           capture_output=True).returncode != 0:
        pytest.skip("cannot mount a tmpfs here")
    yield mnt
    subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def test_a_real_full_tmpfs_stops_the_log_and_the_caller_goes_on(small_tmpfs, caplog):
    caplog.set_level(logging.WARNING)
    log = SampleLog(small_tmpfs, LogLimits(flush_entries=200))
    t0 = time.perf_counter()
    for s in random_samples(30_000):
        log.put(s)
    put_s = time.perf_counter() - t0
    log.close()
    assert log.failure is not None, log.counters
    assert len([r for r in caplog.records if "stopped" in r.getMessage()]) == 1
    assert log.written + log.dropped == 30_000
    # what reached the disk still reads (up to its last complete line)
    rec = read_recording(log_files(small_tmpfs)[0], strict=False)
    assert 0 < len(rec) <= log.written
    assert put_s < 30  # not a timing assertion on speed: only that put() never waited on the stuck disk


def test_a_read_only_filesystem_stops_the_log_with_one_warning(small_tmpfs, caplog):
    caplog.set_level(logging.WARNING)
    subprocess.run(["mount", "-o", "remount,ro", str(small_tmpfs)], check=True)
    log = SampleLog(small_tmpfs / "logs")
    for s in random_samples(100):
        log.put(s)
    log.close()
    assert log.failure is not None
    msgs = [r.getMessage() for r in caplog.records if "stopped" in r.getMessage()]
    assert len(msgs) == 1 and "read-only" in msgs[0]


def test_a_file_cut_anywhere_reads_up_to_its_last_complete_line(tmp_path):
    data = random_samples(3000)
    with SampleLog(tmp_path / "logs", LogLimits(flush_entries=250)) as log:
        for s in data:
            log.put(s)
    (path,) = log_files(tmp_path / "logs")
    whole = path.read_bytes()
    for cut in (len(whole) // 3, len(whole) // 2 + 7, len(whole) - 5):
        cut_path = tmp_path / f"cut{cut}.csv.gz"
        cut_path.write_bytes(whole[:cut])
        rec = read_recording(cut_path, strict=False)
        assert 0 < len(rec) <= len(data)   # the last cut loses only the gzip trailer
        assert_same(rec, data[:len(rec)])


KILLED_LOGGER = """
import sys, time
sys.path.insert(0, {tests!r})
from support.random_samples import random_samples
from ahrsd.drivers.rotating_log import LogLimits
from ahrsd.drivers.sample_log import SampleFile, SampleLog
log = SampleLog({d!r}, LogLimits(max_file_bytes=8000, flush_entries=50, flush_interval_s=0.01))
k = 0
while True:
    for s in random_samples(200, t0=k * 200 / 819.2):
        log.put(s)
    k += 1
    time.sleep(0.002)
"""


def test_a_kill_during_rotation_leaves_every_file_readable(tmp_path):
    d = tmp_path / "logs"
    proc = subprocess.Popen([sys.executable, "-c", KILLED_LOGGER.format(tests=str(Path(__file__).parent), d=str(d))])
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and len(list(d.glob("*.csv.gz"))) < 6:
            time.sleep(0.05)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    files = log_files(d)
    assert len(files) >= 6
    for p in files:
        if p == files[-1] and p.stat().st_size < 30:   # killed within the open: not even the gzip header
            continue
        t = [s.t_s for s in iter_samples(p, strict=False)]   # none raises; the last may be cut, or hold only
        assert np.all(np.diff(t) > 0)                        # its header (killed before its first flush)
        if p != files[-1]:
            assert len(t) > 0
        side = json.loads(Path(str(p) + ".json").read_text())
        assert side["file"] == p.name
    assert all(json.loads(Path(str(p) + ".json").read_text())["closed"] for p in files[:-1])


def test_the_tlog_reads_in_pymavlink_and_mavlogdump(tmp_path):
    from pymavlink import mavutil
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=200)
    frames = [mav.heartbeat_encode(18, 8, 0, 0, 4).pack(mav) for _ in range(3)]
    frames += [mav.attitude_encode(1000 * k, 0.1 * k, -0.2, 1.5, 0, 0, 0).pack(mav) for k in range(5)]
    with TlogLog(tmp_path) as tlog:
        for k, frame in enumerate(frames):
            tlog.put((1.7e9 + k * 0.1, frame))
    (path,) = log_files(tmp_path, ".tlog")
    conn = mavutil.mavlink_connection(str(path), dialect="ardupilotmega")
    got = []
    while (m := conn.recv_match()) is not None:
        got.append(m)
    assert [m.get_type() for m in got] == ["HEARTBEAT"] * 3 + ["ATTITUDE"] * 5
    assert [round(m.roll, 5) for m in got[3:]] == [round(0.1 * k, 5) for k in range(5)]
    assert got[4]._timestamp == pytest.approx(1.7e9 + 0.4, abs=1e-5)
    dump = shutil.which("mavlogdump.py", path=os.path.dirname(sys.executable)) or shutil.which("mavlogdump.py")
    if dump is None:
        pytest.skip("mavlogdump.py not installed")
    out = subprocess.run([sys.executable, dump, "--types", "ATTITUDE", str(path)], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.count("ATTITUDE") == 5 and "roll : 0.4" in out.stdout


def test_a_tlog_cut_mid_frame_reads_up_to_its_last_complete_frame(tmp_path):
    from pymavlink import mavutil
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=200)
    with TlogLog(tmp_path / "logs") as tlog:
        for k in range(10):
            tlog.put((1.7e9 + k, mav.attitude_encode(k, 0.01 * k, 0, 0, 0, 0, 0).pack(mav)))
    (path,) = log_files(tmp_path / "logs", ".tlog")
    whole = path.read_bytes()
    cut = tmp_path / "cut.tlog"
    cut.write_bytes(whole[: len(whole) - 7])     # the last frame torn
    conn = mavutil.mavlink_connection(str(cut), dialect="ardupilotmega")
    got = []
    while (m := conn.recv_match(type="ATTITUDE")) is not None:
        got.append(m.time_boot_ms)
    assert got == list(range(9))
