"""drivers.iio_source against the kernel's adis16400 IIO record format, worked by hand from the driver's channel
table (drivers/iio/imu/adis16400.c adis16400_channels[], industrialio-buffer.c iio_compute_scan_bytes), and the
simulated IIO device (drivers.simulated_iio). The simulated device through the whole daemon (`ahrsd run --iio`, an
interrupt outage counted exactly, every record reaching the daemon) is tests/test_iio_rate.py's daemon test, whose
one daemon also shows the rate it wrote."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from ahrsd.core.sample import SampleFlags
from ahrsd.drivers.iio_source import IioSource, ScanType, record_layout
from ahrsd.drivers.simulated_iio import SCAN_ELEMENTS, SimulatedIioDevice, scan_record
from support.iio_rig import take_samples

# One record, by hand: 12 big-endian 16-bit words as the chip's burst gives them (bit 15 ND, bit 14 EA, then
# 14-bit two's complement; TEMP_OUT/AUX_ADC 12-bit), scan indices 0-9, 11, 16 in that order, 2 bytes each, the
# s64 little-endian time stamp at byte 24 (8-aligned already), 32 bytes in all.
WORDS = [0x8814,   # supply: ND, 2068 LSB × 2.418 mV = 5.000424 V
         0x8002,   # gyro x: ND, +2 LSB (EngineerZone 81805's worked word)
         0xBFF9,   # gyro y: ND, 0x3FF9 = -7 LSB
         0x8000,   # gyro z: 0
         0x812C,   # accel x: +300 LSB
         0xBED4,   # accel y: 0x3ED4 = -300 LSB
         0x8BB8,   # accel z: +3000 LSB
         0x8064,   # magn x: +100 LSB
         0xBF9C,   # magn y: 0x3F9C = -100 LSB
         0x8000,   # magn z: 0
         0x8FFF,   # temp: 12-bit 0xFFF = -1 LSB
         0x8000]   # aux: 0
STAMP_NS = 1234567890123                                   # 0x0000011F71FB04CB
RECORD_HEX = ("8814" "8002" "bff9" "8000" "812c" "bed4" "8bb8" "8064" "bf9c" "8000" "8fff" "8000"
              "cb04fb711f010000")


def test_the_simulated_kernel_writes_the_record_worked_by_hand():
    assert scan_record(WORDS, STAMP_NS, list(SCAN_ELEMENTS)) == bytes.fromhex(RECORD_HEX)


def test_layout_pads_like_iio_compute_scan_bytes():
    s14, ts = ScanType.parse("be:s14/16>>0"), ScanType.parse("le:s64/64>>0")
    elems, size = record_layout([("in_anglvel_x", 1, s14), ("in_timestamp", 17, ts)])
    assert [(e.name, e.offset) for e in elems] == [("in_anglvel_x", 0), ("in_timestamp", 8)] and size == 16
    elems, size = record_layout([(f"c{i}", i, s14) for i in range(9)] + [("in_timestamp", 17, ts)])
    assert elems[-1].offset == 24 and size == 32               # 18 bytes of data, padded to the s64's 8
    assert ScanType.parse("be:u12/16>>4").values(np.array([0xFFF0], dtype=">u2"))[0] == 0xFFF
    assert ScanType.parse("le:s64/64>>0").values(np.array([-5], dtype="<i8").view("<u8"))[0] == -5


@pytest.fixture
def device(tmp_path):
    dev = SimulatedIioDevice(tmp_path, scenario="static", seed=2)
    yield dev
    dev.close()


def started(device) -> IioSource:
    src = IioSource(str(device.sysfs))
    src.start()
    return src


def test_decoding_the_hand_worked_record(device):
    src = started(device)
    assert (device.sysfs / "current_timestamp_clock").read_text().strip() == "monotonic"
    assert all((device.sysfs / "scan_elements" / f"{n}_en").read_text().strip() == "1" for n, _, _ in SCAN_ELEMENTS)
    assert src.record_bytes == 32
    (s,) = src.decode(bytes.fromhex(RECORD_HEX))
    assert s.t_s == pytest.approx(1234.567890123, abs=1e-9)
    np.testing.assert_allclose(s.gyro_rad_s, [0.001746, -0.006111, 0.0], atol=1e-12)      # × 0.000873
    np.testing.assert_allclose(s.accel_m_s2, [9.8055, -9.8055, 98.055], atol=1e-9)        # × 0.032685
    np.testing.assert_allclose(s.mag_ut, [5.0, -5.0, 0.0], atol=1e-12)                    # × 0.0005 G × 100
    assert s.temp_c == pytest.approx(24.78, abs=1e-9)         # (-1 + 178) × 140 m°C
    assert s.supply_v == pytest.approx(5.000424, abs=1e-9)
    assert s.flags & SampleFlags.NEW_DATA and not s.flags & (SampleFlags.ALARM | SampleFlags.GAP_BEFORE)


def test_flags_stale_records_and_gaps_from_the_kernel_time_stamps(device):
    src = started(device)
    period_ns = 1e9 / 819.202
    recs = []
    for k in (0, 1, 2, 5, 6, 7):
        words = list(WORDS)
        if k == 6:
            words[1] |= 0x4000                                  # EA: the chip flags an alarm
        if k == 7:
            words = [w & 0x7FFF for w in words]                 # ND clear: not a new sample
        recs.append(scan_record(words, int(STAMP_NS + k * period_ns + (300 if k % 2 else -300)),
                                list(SCAN_ELEMENTS)))
    out = src.decode(b"".join(recs))
    assert [s.counter for s in out] == [0, 1, 2, 5, 6]
    assert [bool(s.flags & SampleFlags.GAP_BEFORE) for s in out] == [False, False, False, True, False]
    assert out[-1].flags & SampleFlags.ALARM
    c = src.counters()
    assert c["lost_samples_host"] == 2 and c["gaps"] == 1 and c["stale"] == 1 and c["ea_flags"] == 1


def test_garbage_and_repeated_records_are_no_samples_and_a_reading_beyond_full_scale_is_saturated(device):
    """By the datasheet's ranges: gyro ±300 °/s at 0.05 °/s/LSB is 6000 LSB. A gyro word of 8000 LSB is beyond
    any reading the chip reports (garbage: more than 1.25 × full scale), 7400 LSB is a saturated reading (a sample,
    flagged invalid); a record stamped at the time of the one before is the same record again (not a sample)."""
    src = started(device)
    period_ns = 1e9 / 819.202

    def record(k: int, gyro_x_lsb: int = 2) -> bytes:
        words = list(WORDS)
        words[1] = 0x8000 | gyro_x_lsb                          # ND, positive 14-bit value
        return scan_record(words, int(STAMP_NS + k * period_ns), list(SCAN_ELEMENTS))

    out = src.decode(b"".join([record(0), record(1, 8000), record(2), record(3, 7400), record(3, 7400), record(4)]))
    assert [s.counter for s in out] == [0, 2, 3, 4]
    saturated = [bool(s.flags & SampleFlags.GYRO_SATURATED and s.flags & SampleFlags.GYRO_INVALID) for s in out]
    assert saturated == [False, False, True, False]
    other = SampleFlags.ACCEL_SATURATED | SampleFlags.ACCEL_INVALID | SampleFlags.MAG_SATURATED | SampleFlags.MAG_INVALID
    assert not any(s.flags & other for s in out)              # the gyro's word alone: the other sensors are valid
    c = src.counters()
    assert c["garbage_frames"] == 1 and c["timestamp_backwards"] == 1


def test_the_simulated_device_streams_what_the_chip_produced(device):
    src = started(device)
    got = []
    t_end = time.monotonic() + 30.0
    while len(got) < 400 and time.monotonic() < t_end:
        got += src.poll()
        time.sleep(0.02)
    # until records stamped (CLOCK_MONOTONIC, as the source asks the kernel for) 0.5 s after the stall's end have
    # come, whatever came before: a test starved on a loaded machine may take the kernel buffer's backlog of well
    # over 1200 records in one poll, all from before the "kernel" saw the stall
    n_at_stall = len(got)
    stall_asked_s = time.monotonic()
    device.stall(0.1)
    while (len(got) < n_at_stall + 400 or got[-1].t_s < stall_asked_s + 0.6) and time.monotonic() < t_end:
        got += src.poll()
        time.sleep(0.02)
    src.close()
    assert len(got) >= n_at_stall + 400 and got[-1].t_s >= stall_asked_s + 0.6
    steps = np.diff([s.t_s for s in got])
    assert np.all(steps > 0)
    c = src.counters()
    lost = c["lost_samples_host"]
    assert lost >= 0.1 * 819.2 * 0.9                            # the stall, at least
    assert got[-1].counter - got[0].counter + 1 == len(got) + lost
    # static scenario: gravity along -z in the sensor frame, within the datasheet's bias and noise
    assert np.mean([s.accel_m_s2[2] for s in got]) == pytest.approx(-9.81, abs=0.8)


def test_a_missing_iio_device_is_one_line_not_a_traceback(tmp_path, capsys):
    from ahrsd.cli.main import main

    code = main(["run", "--iio", str(tmp_path / "sys/bus/iio/devices/iio:device3"), "--state-dir",
                 str(tmp_path / "state"), "--no-log", "--status-line", "off"])
    err = capsys.readouterr().err
    assert code == 1 and "iio:device3" in err and "Traceback" not in err


def _iio_cfg(device, reader="auto"):
    from ahrsd.drivers.source_settings import SensorSettings

    return SensorSettings(source="iio", iio_device=str(device.sysfs), reader=reader)


def _drain(src, got: list, errors: list, quiet_s: float = 0.2) -> None:
    """Read until the source has had nothing new for quiet_s."""
    quiet_since = time.monotonic()
    while time.monotonic() - quiet_since < quiet_s:
        n = len(got)
        take_samples(src, n + 1, time.monotonic() + 0.05, got, errors)
        if len(got) > n:
            quiet_since = time.monotonic()


def test_the_reader_loses_nothing_while_the_kernel_buffer_holds_and_counts_an_overflow(tmp_path):
    """The kernel buffer is the only place a scan can be lost: a reader that stops for longer than the buffer
    loses exactly the scans that did not fit (counted from the time stamps, equal to the kernel's drops); one
    that stops for less loses none, however late the simulated kernel's own process runs."""
    from ahrsd.drivers.source import open_source

    device = SimulatedIioDevice(tmp_path / "iio", scenario="static", seed=4)
    try:
        device.wait_ready()
        src = open_source(_iio_cfg(device))
        src.inner.buffer_length = 128                          # 0.16 s of scans (the kernel's default length)
        src.inner.start()
        got, errors = [], []
        t_end = time.monotonic() + 60.0
        take_samples(src, 400, t_end, got, errors)
        src._inner_lock.acquire()                               # the reader stops reading (holds the source)
        time.sleep(0.6)                                         # ≈ 490 scans: 128 fit, the rest are dropped
        src._inner_lock.release()
        take_samples(src, len(got) + 800, t_end, got, errors)
        dropped_by_kernel = device.stats["overflow_dropped"]
        src.close()
    finally:
        device.close()
    lost = src.counters()["lost_samples_host"]
    assert dropped_by_kernel > 0.6 * 819.2 - 128 - 100 and not errors
    assert lost == device.lost_truth() == dropped_by_kernel
    assert got[-1].counter - got[0].counter + 1 == len(got) + lost

    device = SimulatedIioDevice(tmp_path / "iio2", scenario="static", seed=4)
    try:
        device.wait_ready()
        src = open_source(_iio_cfg(device))                     # the default buffer: 8192 scans, 10 s
        got, errors = [], []
        t_end = time.monotonic() + 60.0
        take_samples(src, 400, t_end, got, errors)
        src._inner_lock.acquire()
        time.sleep(1.0)
        src._inner_lock.release()
        take_samples(src, len(got) + 1600, t_end, got, errors)
        src.close()
        truth, dropped = device.lost_truth(), device.stats["overflow_dropped"]
    finally:
        device.close()
    assert len(got) >= 2000 and not errors
    assert src.counters()["lost_samples_host"] == truth == dropped == 0
    assert got[-1].counter - got[0].counter + 1 == len(got)


def test_a_vanished_iio_device_is_reopened_counted_and_logged(tmp_path, caplog):
    from ahrsd.drivers.errors import BusError
    from ahrsd.drivers.source import open_source

    device = SimulatedIioDevice(tmp_path / "iio", scenario="static", seed=6)
    try:
        device.wait_ready()
        src = open_source(_iio_cfg(device))
        got, errors = [], []
        t_end = time.monotonic() + 90.0
        take_samples(src, 400, t_end, got, errors)
        assert not errors
        device.remove()                                        # unbound: the stream ends, sysfs and node go
        n_before = len(got)
        while not errors and time.monotonic() < t_end:
            take_samples(src, len(got) + 1, min(t_end, time.monotonic() + 0.2), got, errors)
        assert errors and all(isinstance(e, BusError) for e in errors)     # the daemon is told: sensor failed
        time.sleep(0.5)
        device.recreate()                                      # probed again: channels and buffer disabled
        take_samples(src, len(got) + 800, t_end, got, errors)
        # the truth and the count over the same records: the device writes nothing more for 2 s (an interrupt
        # outage from now on) and the source reads all it wrote. Otherwise a scan the full buffer dropped among the
        # records still in the pipe is in the truth before the source has seen the gap (1173 counted against 1174
        # once under load)
        device.stall(2.0)
        _drain(src, got, errors)
        counters = src.counters()
        truth = device.lost_truth()
        src.close()
    finally:
        device.close()
    assert len(got) >= n_before + 800
    assert counters["device_lost"] == 1 and counters["reopens"] == 1
    assert (device.sysfs / "scan_elements" / "in_anglvel_x_en").read_text().strip() == "1"
    assert (device.sysfs / "current_timestamp_clock").read_text().strip() == "monotonic"
    # the outage's samples are counted lost, against the chip samples no record carried
    lost = counters["lost_samples_host"]
    assert lost == truth >= 0.5 * 819.2 * 0.9
    assert got[-1].counter - got[0].counter + 1 == len(got) + lost
    assert np.all(np.diff([s.t_s for s in got]) > 0)
    messages = [r.getMessage() for r in caplog.records]
    assert any("lost" in m and "re-opening" in m for m in messages)
    assert any(" back " in m for m in messages)


def test_the_udev_rule_opens_every_sysfs_file_the_source_writes(device):
    """Under systemd the daemon is not root: systemd/99-ahrsd-iio.rules must give its group every sysfs file
    the source writes — channels, buffer length and enable, time stamp clock, trigger (an empty one too), and the
    sampling rate when [sensor] rate_hz asks for one. What it writes is read off the simulated sysfs tree: every
    file's modification time is set back first, and the files written are those whose time moved (the rate
    attribute is a FIFO, replaced by a fresh one when read: it counts as written, which it is here)."""
    import fnmatch
    import os
    import re

    rule = (Path(__file__).resolve().parents[1] / "systemd" / "99-ahrsd-iio.rules").read_text()
    (loop,) = re.findall(r"for f in ([^;]+);", rule)
    opened = loop.split()
    (device.sysfs / "trigger" / "current_trigger").write_text("\n")     # a kernel with no trigger set yet
    long_ago_s = 1_000_000_000
    files = [p for p in device.sysfs.rglob("*") if p.is_file() or p.is_fifo()]
    for p in files:
        os.utime(p, (long_ago_s, long_ago_s))
    src = IioSource(str(device.sysfs), rate_hz=204.8)
    src.start()
    try:
        src._open_buffer()
    finally:
        src.close()
    written = [p.relative_to(device.sysfs).as_posix() for p in files if p.stat().st_mtime != long_ago_s]
    assert {"buffer/enable", "buffer/length", "current_timestamp_clock", "trigger/current_trigger",
            "sampling_frequency"} <= set(written)
    assert any(w.startswith("scan_elements/") for w in written)
    assert [w for w in written if not any(fnmatch.fnmatch(w, p) for p in opened)] == []
    assert 'GROUP="iio"' in rule and "SupplementaryGroups=iio" in \
        (Path(__file__).resolve().parents[1] / "systemd" / "ahrsd-iio.conf").read_text()
