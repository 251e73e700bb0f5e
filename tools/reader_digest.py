"""An md5 digest of what the chip reader's per-read path hands over: the check that making the reader cheaper
leaves what it reads, its time stamps and its sample indices bit-identical.

    .venv/bin/python tools/reader_digest.py              # one line per case and one over all of them
    .venv/bin/python tools/reader_digest.py --reads 5000  # shorter runs (a quick look; the default is the check)

Run it in two checkouts (the same command in each worktree) and compare the lines. Each case reads the simulated
ADIS16405 (the boat, seed 3, at 819.2 SPS) through the daemon's one timing path (drivers.chip_source.ChipSource:
the driver, the SampleTimer, the index checks) on a stepped host clock: every read starts at the timer's next
read time plus a lateness drawn from a seeded generator (mostly tens of µs, at times a quarter period, a period
or more: a preempted reader), and every SPI transfer moves the clock on by a drawn duration (at times longer
than a period: a transfer preempted inside). Hashed, read by read: what the read gave (a sample's hand-over
record, the bytes drivers.process_source.pack makes of it; nothing; or the FrameError), and the timer's state
after it (phase bracket, index, the newest index a read may have consumed); at the end the driver's and the
source's counters. Cases: `clean` (no fault), `faults` (the burst bug, alarms, a stuck and a saturated axis,
garbage and short frames, a data-ready stall: drivers.faults). Both with ImuSamples and with the reader
process's records (`samples_as_records`).
"""

from __future__ import annotations

import argparse
import hashlib
import struct
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

SEED = 3


class _HostClock:
    """The host clock of the reads and of the chip: moved on only by the read loop and by the bus."""

    def __init__(self, t: float = 100.0):
        self.t = t

    def __call__(self) -> float:
        return self.t


class _TimedBus:
    """The simulated chip's SPI bus; each transfer moves the host clock on by a drawn duration."""

    def __init__(self, chip, clock: _HostClock, rng: np.random.Generator, period_s: float):
        self.chip, self.clock, self.rng, self.period_s = chip, clock, rng, period_s

    def transfer(self, tx: bytes, speed_hz: int, delay_us: int = 0) -> bytes:
        rx = self.chip.transfer(tx, speed_hz, delay_us)
        u = self.rng.random()
        took = 30e-6 + 40e-6 * self.rng.random()
        if u < 0.02:
            took += 0.5 * self.period_s          # preempted inside the transfer
        elif u < 0.025:
            took += 1.2 * self.period_s          # longer than a period: not checkable
        self.clock.t += took
        return rx

    def sleep(self, seconds: float) -> None:
        self.clock.t += max(0.0, seconds)

    def close(self) -> None:
        self.chip.close()


def _fault_plan(kind: str):
    from ahrsd.drivers.faults import FaultPlan

    plan = FaultPlan(seed=SEED)
    if kind == "faults":
        plan.add("burst_bug", start_sample=500, stop_sample=3000, probability=0.3)
        plan.add("alarm", start_sample=3500, stop_sample=3600)
        plan.add("stuck_axis", start_sample=4000, stop_sample=5200, axis=1)
        plan.add("stuck_axis", start_sample=5400, stop_sample=6400, axis=7)
        plan.add("saturation", start_sample=6600, stop_sample=6700, axis=0)
        plan.add("saturation", start_sample=6800, stop_sample=6900, axis=4, sign=-1)
        plan.add("garbage", start_sample=7000, stop_sample=9000, probability=0.02)
        plan.add("short_read", start_sample=9200, stop_sample=9300, probability=0.1)
        plan.add("stall", start_sample=9500, stop_sample=9700)
    return plan


def read_once(src, clock: _HostClock, rng: np.random.Generator, period: float) -> bytes:
    """One read of the chip source at its next read time plus a drawn lateness: what it gave as bytes (the
    sample's hand-over record, b"-" for none, or the error's type and message)."""
    from ahrsd.drivers.errors import DriverError
    from ahrsd.drivers.process_source import pack

    u = rng.random()
    late = 20e-6 + 60e-6 * rng.random()
    if u < 0.05:
        late += 0.25 * period
    elif u < 0.06:
        late += (1.0 + 3.0 * rng.random()) * period
    clock.t = max(clock.t, src.next_read_time()) + late
    try:
        s = src.read_one(clock.t)
    except DriverError as exc:
        return f"E{type(exc).__name__}:{exc}".encode()
    return b"-" if s is None else pack([s])


def case_digest(kind: str, records: bool, reads: int) -> str:
    from ahrsd.drivers import registers as R
    from ahrsd.drivers.adis16405 import Adis16405
    from ahrsd.drivers.chip_source import ChipSource
    from ahrsd.drivers.simulated import SimulatedAdis16405
    from ahrsd.drivers.sample_timer import StallAwareSampleTimer

    rate = R.sample_rate_hz(R.SMPL_PRD_DEFAULT)
    period = 1.0 / rate
    clock = _HostClock()
    rng = np.random.default_rng(SEED)
    chip = SimulatedAdis16405("boat", seed=SEED, clock=clock, faults=_fault_plan(kind))
    bus = _TimedBus(chip, clock, rng, period)
    driver = Adis16405(bus, samples_as_records=records)
    driver.start()
    src = ChipSource(driver, bus, "digest", clock=clock, timer=StallAwareSampleTimer(period))
    h = hashlib.md5()
    pack_f = struct.Struct("<4d2q").pack
    for _ in range(reads):
        h.update(read_once(src, clock, rng, period))
        t = src.timer
        h.update(pack_f(t.lo if t.lo is not None else -1.0, t.hi if t.hi is not None else -1.0, t._t_lo, t._t_hi,
                        t.k, t._consumed_upto))
    h.update(repr(sorted(src.counters().items())).encode())
    chip.close()
    return h.hexdigest()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--reads", type=int, default=12000)
    args = ap.parse_args()
    total = hashlib.md5()
    for kind in ("clean", "faults"):
        for records in (False, True):
            d = case_digest(kind, records, args.reads)
            total.update(d.encode())
            print(f"{kind:6s} {'records' if records else 'samples'} {d}")
    print(f"all {total.hexdigest()}")


if __name__ == "__main__":
    main()
