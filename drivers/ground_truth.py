"""Ground truth of a simulated chip next to the sensor source that reads it: which chip samples were read, and
why the others were lost (in a fault window, right after a reconnect, or for no injected reason). The soak
(bench/soak.py) and the reliability tests judge the daemon's own loss accounting against it. Only ever
wrapped around a source reading `SimulatedAdis16405`; the real sensor's path has none of it.

It also measures what the simulator costs the process that reads it (`sensor_simulated_cpu_s`: the thread CPU
time spent inside the simulated chip's transfers — its register model, on hardware the kernel's spidev — and
in this truth bookkeeping, from the first read on), so that a benchmark can report the daemon's own CPU apart
from the simulated hardware's (bench/latency.py, docs/daemon.md "Performance"). Reading a thread's CPU clock is
a system call, many times dearer than CLOCK_MONOTONIC, so one read in MEASURE_EVERY is measured and the sum
scaled to every read: timing every read would charge the reader a visible share of a core (the figures:
docs/daemon.md "Performance").
"""

from __future__ import annotations

import logging
import time

from ahrsd.drivers.registers import GLOB_CMD
from ahrsd.drivers.source_interface import LiveSource

log = logging.getLogger(__name__)

_thread_time = time.thread_time     # CLOCK_THREAD_CPUTIME_ID: the reading thread's CPU, not the wall time
MEASURE_EVERY = 17                  # reads between two measured ones (prime: the chip's 256-sample blocks
                                    # are computed every 256 reads, and a stride dividing it would always
                                    # or never catch one)

# faults during which the sample flow stops or frames are rejected: samples lost there are explained
FLOW_STOPPING_FAULTS = ("bus_error", "stall", "garbage", "short_read", "self_test_fail")


class ChipBus:
    """The simulated chip as the SPI bus (drivers.spi.SpiBus: transfer, sleep, close) and its clock (`now`; a
    benchmark places chip time on the host's), each passed on as it is: what a tap in front of the chip overrides
    the rest of (the taps below; tests' fakes, tests/support/chip_bus.py)."""

    def __init__(self, chip):
        self.chip = chip

    def transfer(self, tx: bytes, speed_hz: int, delay_us: int = 0) -> bytes:
        return self.chip.transfer(tx, speed_hz, delay_us)

    def sleep(self, seconds: float) -> None:
        self.chip.sleep(seconds)

    def close(self) -> None:
        self.chip.close()

    def now(self) -> float:
        return self.chip.now()


class BurstIndexTap(ChipBus):
    """The simulated chip as the SPI bus, noting the chip's sample index at each burst: the ground truth of
    the sample a burst returned (`chip.sample_index` after the read can be one further when the driver went
    on with a register read — burst-bug check, DIAG_STAT — during which the chip produced the next sample)."""

    def __init__(self, chip):
        super().__init__(chip)
        self.burst_index = -1
        self.measuring = False        # time the transfers (GroundTruthSource's measured reads)
        self.cpu_s = 0.0              # thread CPU time inside the simulated chip's transfers, while measuring

    def transfer(self, tx: bytes, speed_hz: int, delay_us: int = 0) -> bytes:
        if self.measuring:
            t0 = _thread_time()
            try:
                return self._transfer(tx, speed_hz, delay_us)
            finally:
                self.cpu_s += _thread_time() - t0
        return self._transfer(tx, speed_hz, delay_us)

    def _transfer(self, tx: bytes, speed_hz: int, delay_us: int) -> bytes:
        rx = super().transfer(tx, speed_hz, delay_us)
        if tx[0] == GLOB_CMD and tx[1] == 0:          # 0x3E00 starts a burst read
            self._on_burst()
        return rx

    def _on_burst(self) -> None:
        """A burst read has just returned the chip's current sample: note what belongs to that sample."""
        self.burst_index = self.chip.sample_index


class BurstTruthTap(BurstIndexTap):
    """A BurstIndexTap that also notes the truth attitude (body->NED, wxyz) of the sample each burst returned,
    for `ahrsd record --sim`'s truth columns: the chip's own `output_truth_q_wxyz` after the read is a later
    sample's when the driver went on with a register read (burst-bug check, DIAG_STAT) during which the chip
    produced the next sample."""

    def __init__(self, chip):
        super().__init__(chip)
        self.burst_truth_q_wxyz = None

    def _on_burst(self) -> None:
        super()._on_burst()
        truth = self.chip.output_truth_q_wxyz     # a row of the chip's block: copied, ours to keep
        self.burst_truth_q_wxyz = None if truth is None else truth.copy()


class GroundTruthSource(LiveSource):
    """A per-sample source over `BurstIndexTap(chip)` plus the chip's truth (`truth_stats`, in `counters()`
    as sensor_*; chip_first/last_index_read). Fault windows of the chip's FaultPlan are rebased to count chip
    samples from the start (start-up faults) and from the first read (run-time faults): the chip ran while
    the daemon was loading."""

    per_sample = True
    monotonic_offset_s = 0.0

    def __init__(self, inner, chip, tap: BurstIndexTap):
        self.inner = inner
        self.chip = chip
        self.tap = tap
        self.truth_stats = {"lost_in_fault_windows": 0, "lost_after_reconnect": 0, "lost_outside_faults": 0,
                            "index_mismatches": 0}
        self.first_chip_index: int | None = None
        self.last_chip_index: int | None = None
        self._last_counter = -1
        self._opens_accounted = 0
        self._reads_started = False
        # the simulated chip's transfers are timed through a BurstIndexTap (a test's own tap is not timed)
        self._timed_tap = tap if isinstance(tap, BurstIndexTap) else None
        self._reads = 0                  # reads since the first, and of them measured (MEASURE_EVERY)
        self._measured_reads = 0
        self._bookkeeping_cpu_s = 0.0     # thread CPU time of this truth bookkeeping (`_account`), measured reads
        self._reads_since = 0.0          # CLOCK_MONOTONIC of the first read
        self._planned: dict[int, tuple[int, int | None]] | None = None   # id(fault): its plan's (start, stop)

    # what the inner source says
    description = property(lambda self: self.inner.description)
    sample_rate_hz = property(lambda self: self.inner.sample_rate_hz)
    bus = property(lambda self: self.inner.bus)
    driver = property(lambda self: self.inner.driver)
    timer = property(lambda self: self.inner.timer)

    @property
    def stats(self) -> dict:
        return {**self.inner.stats, **self.truth_stats}

    def _successful_opens(self) -> int:
        return self.inner.stats["open_attempts"] - self.inner.stats["open_failures"]

    def _rebase_faults(self, kinds_excluded=()) -> None:
        """Place the faults (but `kinds_excluded`) at their planned sample counted from the next sample. Each
        from its plan, not from where an earlier rebase put it: run-time faults are placed at the start (so
        the start's transfers do not meet them) and again at the first read, whose base alone must count."""
        base = max(0, self.chip.sample_index + 1, self.chip.first_index_after_now())
        if self._planned is None:
            self._planned = {id(f): (f.start_sample, f.stop_sample) for f in self.chip.faults.faults}
        for f in self.chip.faults.faults:
            if f.kind.value in kinds_excluded:
                continue
            start, stop = self._planned.get(id(f), (f.start_sample, f.stop_sample))
            f.start_sample = start + base
            f.stop_sample = None if stop is None else stop + base

    def start(self) -> None:
        self._rebase_faults()
        self.inner.start()
        self._opens_accounted = self._successful_opens()

    def read_one(self, now: float):
        if not self._reads_started:
            self._reads_started = True
            self._rebase_faults(kinds_excluded=("self_test_fail",))   # run-time faults: from the first read
            self._reads_since = time.monotonic()
        self._reads += 1
        if (self._reads - 1) % MEASURE_EVERY:
            s = self.inner.read_one(now)
            if s is not None:
                self._account(s)
            return s
        return self._measured_read(now)

    def _measured_read(self, now: float):
        """A read whose simulator parts are timed: the chip's transfers (the tap) and the bookkeeping."""
        self._measured_reads += 1
        tap = self._timed_tap
        if tap is None:
            s = self.inner.read_one(now)
        else:
            tap.measuring = True
            try:
                s = self.inner.read_one(now)
            finally:
                tap.measuring = False
        if s is not None:
            t0 = _thread_time()
            self._account(s)
            self._bookkeeping_cpu_s += _thread_time() - t0
        return s

    def _account(self, s) -> None:
        idx = self.tap.burst_index
        prev = self.last_chip_index
        if self.first_chip_index is None:
            self.first_chip_index = idx
        self.last_chip_index = idx
        opens = self._successful_opens()
        reopened, self._opens_accounted = opens != self._opens_accounted, opens
        prev_counter, self._last_counter = self._last_counter, s.counter
        stats = self.truth_stats
        if prev is not None and idx - prev != s.counter - prev_counter:
            stats["index_mismatches"] += 1
            log.debug("sample index mismatch: chip +%d, daemon +%d (flags %s, reopened %s)", idx - prev,
                      s.counter - prev_counter, s.flags, reopened)
        if prev is None or idx - prev <= 1:
            return
        lost = idx - prev - 1
        lo, hi = prev + 1, idx                      # lost chip samples: [lo, hi)
        if any(f.kind.value in FLOW_STOPPING_FAULTS and f.start_sample < hi
               and (f.stop_sample is None or f.stop_sample > lo) for f in self.chip.faults.faults):
            stats["lost_in_fault_windows"] += lost
        elif reopened:
            stats["lost_after_reconnect"] += lost
        else:
            stats["lost_outside_faults"] += lost

    def next_read_time(self) -> float:
        return self.inner.next_read_time()

    def poll(self, now: float | None = None):
        s = self.read_one(self.inner._clock() if now is None else now)
        return [] if s is None else [s]

    def counters(self) -> dict:
        c = self.inner.counters()
        c.update({f"sensor_{k}": v for k, v in self.truth_stats.items()})
        for k in ("producer_waits", "producer_wait_max_us"):      # the simulator's own delays (drivers.simulated)
            if k in self.chip.stats:
                c[f"sensor_{k}"] = self.chip.stats[k]
        if self.first_chip_index is not None:
            c["chip_first_index_read"] = self.first_chip_index
            c["chip_last_index_read"] = self.last_chip_index
        if self._measured_reads:
            # what the simulator cost the reading thread since the first read (the measured reads' CPU, scaled
            # to every read), and over how long: a share of a core that is the simulated hardware's, not the
            # daemon's
            measured = (self._timed_tap.cpu_s if self._timed_tap is not None else 0.0) + self._bookkeeping_cpu_s
            c["sensor_simulated_cpu_s"] = measured * self._reads / self._measured_reads
            c["sensor_simulated_wall_s"] = time.monotonic() - self._reads_since
        return c

    def close(self) -> None:
        self.inner.close()
