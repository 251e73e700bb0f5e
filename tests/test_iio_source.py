"""drivers.iio_source against the kernel's adis16400 IIO record format, worked by hand from the driver's channel
table (drivers/iio/imu/adis16400.c adis16400_channels[], industrialio-buffer.c iio_compute_scan_bytes), and the
simulated IIO device (drivers.simulated_iio) through the whole daemon."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from ahrsd.core.sample import SampleFlags
from ahrsd.drivers.iio_source import IioSource, ScanType, record_layout
from ahrsd.drivers.simulated_iio import SCAN_ELEMENTS, SimulatedIioDevice, scan_record

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


def test_the_simulated_device_streams_what_the_chip_produced(device):
    src = started(device)
    got = []
    t_end = time.monotonic() + 30.0
    while len(got) < 400 and time.monotonic() < t_end:
        got += src.poll()
        time.sleep(0.02)
    device.stall(0.1)
    while len(got) < 1200 and time.monotonic() < t_end:
        got += src.poll()
        time.sleep(0.02)
    src.close()
    assert len(got) >= 1200
    steps = np.diff([s.t_s for s in got])
    assert np.all(steps > 0)
    c = src.counters()
    lost = c["lost_samples_host"]
    assert lost >= 0.1 * 819.2 * 0.9                            # the stall, at least
    assert got[-1].counter - got[0].counter + 1 == len(got) + lost
    # static scenario: gravity along -z in the sensor frame, within the datasheet's bias and noise
    assert np.mean([s.accel_m_s2[2] for s in got]) == pytest.approx(-9.81, abs=0.8)


def test_the_simulated_iio_device_through_the_daemon(tmp_path):
    device = SimulatedIioDevice(tmp_path / "iio", scenario="static", seed=5)
    stats = tmp_path / "stats.json"
    proc = subprocess.Popen([sys.executable, "-m", "ahrsd.cli", "run", "--iio", str(device.sysfs),
                             "--state-dir", str(tmp_path / "state"), "--no-log", "--status-line", "off",
                             "--mavlink", "udpout:127.0.0.1:9", "--stats-file", str(stats)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        t_end = time.monotonic() + 120.0
        while device.stats["records"] < 2000 and time.monotonic() < t_end and proc.poll() is None:
            time.sleep(0.1)
        device.stall(0.25)
        t_more = device.stats["records"] + 2000
        while device.stats["records"] < t_more and time.monotonic() < t_end and proc.poll() is None:
            time.sleep(0.1)
        device.close()                                         # the "kernel" stops; the daemon drains the rest
        time.sleep(1.0)
    finally:
        proc.send_signal(2)
        out, _ = proc.communicate(timeout=30)
    assert proc.returncode in (0, 130), out[-2000:]
    st = json.loads(stats.read_text())
    assert st["source"]["records"] == device.stats["records"] >= 4000
    assert st["pipeline"]["samples"] == device.stats["records"] - st["source"]["stale"]
    truth = device.lost_truth()
    assert truth >= 0.25 * 819.2 * 0.9 and device.stats["overflow_dropped"] == 0
    assert st["pipeline"]["lost_samples"] == st["source"]["lost_samples_host"] == truth, (st, truth)
    assert "through the kernel's IIO driver" in out


def test_a_missing_iio_device_is_one_line_not_a_traceback(tmp_path, capsys):
    from ahrsd.cli.main import main

    code = main(["run", "--iio", str(tmp_path / "sys/bus/iio/devices/iio:device3"), "--state-dir",
                 str(tmp_path / "state"), "--no-log", "--status-line", "off"])
    err = capsys.readouterr().err
    assert code == 1 and "iio:device3" in err and "Traceback" not in err
