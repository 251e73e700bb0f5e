"""The chip source's common read (drivers.chip_source.ChipSource.read_one's own: a clean fresh frame with a certain
index, decoded in one function) gives what the driver's and the timer's general path give: the same record, the
same error, the same timer state and the same counters, read after read, on the clean chip and through every
fault kind; and it is the path the clean chip's reads take."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from ahrsd.drivers import registers as R
from ahrsd.drivers.adis16405 import Adis16405
from ahrsd.drivers.chip_source import ChipSource
from ahrsd.drivers.sample_timer import StallAwareSampleTimer
from ahrsd.drivers.simulated import SimulatedAdis16405
from tools.reader_digest import SEED, _fault_plan, _HostClock, _TimedBus, read_once

PERIOD_S = 1.0 / R.sample_rate_hz(R.SMPL_PRD_DEFAULT)
_DRIVER_STATE = ("counters", "_prev_gx", "_prev_raw9", "_runs", "_stuck", "_any_stuck", "newer_sample_taken",
                 "_burst_supply_lsb", "last_diag_stat")


class _TamperedChip:
    """The simulated chip with every `EVERY`-th burst frame changed by `tamper(n, words)` (the 12 words, ND/EA
    bits included), the frames no fault kind of the simulator makes: an axis at full scale without EA, a
    burst-bug suspect below full scale, EA in one word."""

    EVERY = 40

    def __init__(self, chip, tamper):
        self.chip, self.tamper, self.bursts = chip, tamper, 0

    def transfer(self, tx: bytes, speed_hz: int, delay_us: int = 0) -> bytes:
        rx = self.chip.transfer(tx, speed_hz, delay_us)
        if tx[:2] != R.BURST_COMMAND or len(rx) != R.BURST_FRAME_BYTES:
            return rx
        self.bursts += 1
        if self.bursts % self.EVERY:
            return rx
        words = list(struct.unpack(">12H", rx[2:]))
        self.tamper(self.bursts // self.EVERY, words)
        return rx[:2] + struct.pack(">12H", *words)

    def close(self) -> None:
        self.chip.close()


def _unusual(n: int, words: list[int]) -> None:
    flags = words[1] & (R.ND | R.EA)
    kind = n % 3
    if kind == 0:          # accel Y at full scale, flags as the frame's
        words[5] = (-R.ACCEL_RANGE_LSB & 0x3FFF) | (words[5] & (R.ND | R.EA))
    elif kind == 1:        # X gyro 150 °/s, bit 13 clear: above the burst-bug jump, below full scale
        words[1] = (int(150.0 / R.GYRO_DPS_PER_LSB[300]) & 0x3FFF) | flags
    else:                  # EA in one word only: the words disagree
        words[3] |= R.EA


class _Reader:
    """tools/reader_digest.py's read loop over one simulated chip: `common` False reads every frame through the
    general path (the driver's decode_burst and ChipSource._stamp); True counts the reads the common read kept."""

    def __init__(self, kind: str, common: bool, tamper=None):
        self.clock = _HostClock()
        self.rng = np.random.default_rng(SEED)
        self.chip = SimulatedAdis16405("boat", seed=SEED, clock=self.clock, faults=_fault_plan(kind))
        bus = _TimedBus(_TamperedChip(self.chip, tamper) if tamper else self.chip, self.clock, self.rng, PERIOD_S)
        self.driver = Adis16405(bus, samples_as_records=True)
        self.driver.start()
        self.src = ChipSource(self.driver, bus, "test", clock=self.clock, timer=StallAwareSampleTimer(PERIOD_S))
        self.src._common_timer = common
        self.general = 0                  # frames decoded by the general path (decode_burst)
        decode = self.driver.decode_burst

        def counted(*args):
            self.general += 1
            return decode(*args)

        self.driver.decode_burst = counted

    def read(self) -> bytes:
        return read_once(self.src, self.clock, self.rng, PERIOD_S)

    def state(self) -> tuple:
        d = self.driver
        return (dict(vars(self.src.timer)), self.src.counters(), self.src.lost_samples, self.src.stale_reads,
                *(repr(getattr(d, name)) for name in _DRIVER_STATE))


@pytest.mark.parametrize("kind", ["clean", "faults"])
def test_the_common_read_answers_as_the_general_path(kind):
    general, common = _Reader(kind, common=False), _Reader(kind, common=True)
    reads = 10_000
    for i in range(reads):
        assert common.read() == general.read(), f"read {i}"
        assert common.state() == general.state(), f"read {i}"
    stale = general.src.stale_reads
    taken = reads - common.general
    if kind == "clean":
        # every fresh read but the first, those preempted a period inside the transfer (2.5 % of the bus's
        # transfers are 0.5 or 1.2 periods long) and those whose index the clock leaves open
        assert taken > 0.85 * (reads - stale), (taken, reads, stale)
    else:
        assert common.general > general.general // 10
        assert taken > 0.5 * (reads - stale)


def test_a_newer_sample_taken_goes_the_general_way():
    """After a register read took a newer sample's ND the next burst is new data without ND: the common read
    hands it to the general path (which knows it), and the sample is fresh."""
    reader = _Reader("clean", common=True)
    for _ in range(50):
        reader.read()
    reader.driver.newer_sample_taken = True
    before = reader.general
    reader.clock.t = reader.src.next_read_time() - 0.5 * PERIOD_S     # early: the burst's ND is clear
    s = reader.src.read_one(reader.clock.t)
    assert reader.general == before + 1
    assert s is not None and s.flags & 1            # SampleFlags.NEW_DATA


def test_unusual_frames_go_the_general_way():
    """Frames the simulator's faults do not make (an axis at full scale without EA, a burst-bug suspect below full
    scale, EA in one word: `_unusual`), every 40th burst of the clean chip: the common read gives what the general
    path gives (saturation flagged, the X gyro checked with a register read, the frame rejected)."""
    general, common = _Reader("clean", common=False, tamper=_unusual), _Reader("clean", common=True, tamper=_unusual)
    for i in range(3000):
        assert common.read() == general.read(), f"read {i}"
        assert common.state() == general.state(), f"read {i}"
    c = general.driver.counters
    assert c["saturations"] >= 20 and c["burst_bug_unverified"] + c["burst_bug_recovered"] >= 20
    assert c["garbage_frames"] >= 20
