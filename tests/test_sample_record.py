"""The reader process's cheaper per-read path: the chip driver hands over SampleRecords (drivers.sample_record)
instead of ImuSamples there, and the hand-over bytes must be those of the ImuSample path."""

import math
import struct

import numpy as np
import pytest

from ahrsd.core.sample import SampleFlags
from ahrsd.drivers import registers as R
from ahrsd.drivers.adis16405 import Adis16405
from ahrsd.drivers.process_source import pack, unpack
from ahrsd.drivers.sample_record import SampleRecord
from ahrsd.drivers.simulated import SimulatedAdis16405
from ahrsd.simulation import open_stream

from support.chip_bus import SimulatedChipBus


def _driver(records: bool) -> Adis16405:
    chip = SimulatedAdis16405(open_stream("boat", rate_hz=R.sample_rate_hz(R.SMPL_PRD_DEFAULT), seed=3))
    imu = Adis16405(chip, samples_as_records=records)
    imu.start()
    return imu


def _signed14(word: int) -> int:
    v = word & 0x3FFF
    return v - 0x4000 if v >= 0x2000 else v


class _TapBus(SimulatedChipBus):
    """The simulated chip's SPI bus, keeping the last burst frame (to work the values out by hand)."""

    def __init__(self, chip):
        super().__init__(chip)
        self.last = b""

    def transfer(self, tx, speed_hz, delay_us=0):
        rx = self.chip.transfer(tx, speed_hz, delay_us)
        if tx[:2] == R.BURST_COMMAND:
            self.last = rx
        return rx


def test_record_holds_the_frames_values_in_si_units():
    """Against the datasheet's scales applied by hand to the burst frame's words (14-bit two's complement):
    gyro 0.05 °/s, accel 3.333 mg (of 9.80665 m/s²), mag 0.5 mgauss, supply 2.418 mV, temp 0.14 °C (12 bit) from 25 °C."""
    chip = SimulatedAdis16405(open_stream("boat", rate_hz=R.sample_rate_hz(R.SMPL_PRD_DEFAULT), seed=3))
    bus = _TapBus(chip)
    imu = Adis16405(bus, samples_as_records=True)
    imu.start()
    for _ in range(50):
        rec = imu.read_sample()
        if isinstance(rec, SampleRecord) and rec.flags & SampleFlags.NEW_DATA:
            break
    assert type(rec) is SampleRecord and len(rec) == 15
    words = struct.unpack(">12H", bus.last[2:26])
    raw = [_signed14(w) for w in words[1:10]]
    scales = [math.radians(0.05)] * 3 + [3.333e-3 * 9.80665] * 3 + [0.05] * 3
    want = [r * s for r, s in zip(raw, scales)]
    assert list(rec[1:10]) == pytest.approx(want, rel=1e-12, abs=1e-15)
    assert rec.gyro_rad_s.tolist() == pytest.approx(want[0:3], rel=1e-12)
    assert rec.accel_m_s2.tolist() == pytest.approx(want[3:6], rel=1e-12)
    assert rec.mag_ut.tolist() == pytest.approx(want[6:9], rel=1e-12)
    assert rec.supply_v == pytest.approx((words[0] & 0x3FFF) * 2.418e-3, rel=1e-12)
    t = words[10] & 0x0FFF
    assert rec.temp_c == pytest.approx(25.0 + 0.14 * (t - 0x1000 if t >= 0x800 else t), rel=1e-12)
    assert rec.t_s == rec[0] and rec.counter == rec[14] and rec.flags == rec[12] and rec.diag_stat == rec[13]


def test_records_pack_to_the_bytes_of_the_sample_path():
    """Two drivers on two identical simulated chips, one handing over records, one ImuSamples: the hand-over
    bytes (what the daemon unpacks) are the same, sample by sample, for 2 000 reads of a moving boat."""
    with_records, with_samples = _driver(True), _driver(False)
    recs = [with_records.read_sample() for _ in range(2000)]
    samples = [with_samples.read_sample() for _ in range(2000)]
    assert all(type(r) is SampleRecord for r in recs)
    assert pack(recs) == pack(samples)
    back = unpack(pack(recs))
    assert [s.counter for s in back] == [s.counter for s in samples]
    assert np.array_equal(np.array([s.mag_ut for s in back]), np.array([s.mag_ut for s in samples]))


def test_a_gap_flag_set_on_the_way_keeps_the_rest():
    """threaded_source sets GAP_BEFORE with `with_values(flags=...)` on whatever the driver gave."""
    rec = SampleRecord((1.5, *range(9), 25.0, 5.0, int(SampleFlags.NEW_DATA), 7, 42))
    gapped = rec.with_values(flags=rec.flags | SampleFlags.GAP_BEFORE)
    assert type(gapped) is SampleRecord
    assert gapped.flags == int(SampleFlags.NEW_DATA | SampleFlags.GAP_BEFORE)
    assert gapped[:12] == rec[:12] and gapped.diag_stat == 7 and gapped.counter == 42
    one = unpack(pack([gapped]))[0]
    assert one.flags & SampleFlags.GAP_BEFORE and one.counter == 42 and one.t_s == 1.5


def _first_sample(src, give_up_s: float = 30.0):
    """The source's next sample, read as the daemon's per-sample reader does (at its next read time)."""
    import time

    end = time.monotonic() + give_up_s
    while time.monotonic() < end:
        time.sleep(max(0.0, src.next_read_time() - time.monotonic()))
        s = src.read_one(time.monotonic())
        if s is not None:
            return s
    raise AssertionError("no sample")


def test_records_are_a_setting_of_the_source_not_of_the_process():
    """open_source(samples_as_records=True), as the reader process opens its chip: its driver hands over records,
    also after a re-open (a power loss: drivers.reconnecting); a source opened beside it in the same process
    without the setting reads ImuSamples (the class-wide switch made every driver in the process hand over
    records)."""
    import time

    from ahrsd.core.sample import ImuSample
    from ahrsd.daemon.config import SensorConfig
    from ahrsd.drivers.source import open_source

    cfg = SensorConfig(source="sim", reader="event_loop")
    records = open_source(cfg, clock=time.monotonic, samples_as_records=True)
    plain = open_source(cfg, clock=time.monotonic)
    try:
        assert type(_first_sample(records)) is SampleRecord
        assert type(_first_sample(plain)) is ImuSample
        records.chip.power_cycle()
        records.inner._try_open(time.monotonic())       # the re-open after the bus failure that follows
        assert type(_first_sample(records)) is SampleRecord
        assert type(_first_sample(plain)) is ImuSample
    finally:
        for src in (records, plain):
            src.close()
            src.chip.close()
