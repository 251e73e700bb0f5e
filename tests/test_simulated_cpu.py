"""The simulated hardware measures what it costs the process that runs it, so that bench/latency.py can judge the
daemon's own CPU apart from the simulator's: the simulated chip's transfers and its ground truth's bookkeeping
in the reading thread (drivers.ground_truth), the simulated receiver's writer thread (drivers.gnss.scenario).
Checked against CPU burnt on purpose on either side of the boundary (thread CPU time, not wall time: the figures
hold on a loaded machine)."""

from __future__ import annotations

import time
from types import SimpleNamespace

from ahrsd.drivers import registers as R
from ahrsd.drivers.ground_truth import BurstIndexTap, GroundTruthSource

CHIP_S = 0.002        # CPU of one simulated transfer
DRIVER_S = 0.004      # CPU of the driver's own work around it (the daemon's, not the simulator's)
READS = 20
STARTUP_TRANSFERS = 5


def _spin(cpu_s: float) -> None:
    end = time.thread_time() + cpu_s
    while time.thread_time() < end:
        pass


class BusyChip:
    """The simulated chip as GroundTruthSource sees it; every transfer costs CHIP_S of CPU."""

    sample_rate_hz = 819.2

    def __init__(self):
        self.sample_index = -1
        self.stats: dict = {}
        self.faults = SimpleNamespace(faults=[])

    def now(self) -> float:
        return 0.0

    def first_index_after_now(self) -> int:
        return int(self.now() * self.sample_rate_hz) + 1     # one rate from power-on: the grid is now × rate

    def transfer(self, tx: bytes, speed_hz: int, delay_us: int = 0) -> bytes:
        _spin(CHIP_S)
        self.sample_index += 1
        return bytes(len(tx))


class BusyDriver:
    """A per-sample source on the tap: the start-up's register transfers, then per read a burst and DRIVER_S of
    its own work."""

    def __init__(self, tap):
        self.tap = tap
        self.stats = {"open_attempts": 1, "open_failures": 0}
        self.k = 0

    def start(self) -> None:
        for _ in range(STARTUP_TRANSFERS):
            self.tap.transfer(bytes(2), R.SPI_BURST_HZ)

    def read_one(self, now: float):
        self.tap.transfer(R.BURST_COMMAND + bytes(R.BURST_DATA_BYTES), R.SPI_BURST_HZ)
        _spin(DRIVER_S)
        self.k += 1
        return SimpleNamespace(counter=self.k, flags=0)

    def counters(self) -> dict:
        return {}


def test_the_simulated_chip_counts_its_transfers_from_the_first_read_and_not_the_drivers_work(monkeypatch):
    """Every read's transfer counts (the measured reads' CPU scaled to all), neither the start-up's transfers nor
    the driver's own work; the thread CPU clock (a system call) is read on one read in MEASURE_EVERY only."""
    from ahrsd.drivers import ground_truth

    clock_reads = [0]

    def counted_thread_time() -> float:
        clock_reads[0] += 1
        return time.thread_time()

    monkeypatch.setattr(ground_truth, "_thread_time", counted_thread_time)
    chip = BusyChip()
    tap = BurstIndexTap(chip)
    src = GroundTruthSource(BusyDriver(tap), chip, tap)
    src.start()
    assert "sensor_simulated_cpu_s" not in src.counters()          # nothing read yet
    t0 = time.monotonic()
    for _ in range(READS):
        src.read_one(0.0)
    elapsed = time.monotonic() - t0
    c = src.counters()
    # every read's transfer, and neither the start-up's transfers (10 ms) nor the driver's work (80 ms): the
    # bookkeeping and the timer calls themselves cost microseconds a read
    assert READS * CHIP_S <= c["sensor_simulated_cpu_s"] < READS * CHIP_S + 0.005
    assert 0.0 < c["sensor_simulated_wall_s"] <= elapsed + 0.05
    measured = -(-READS // ground_truth.MEASURE_EVERY)             # reads 1, 1 + MEASURE_EVERY, ...
    assert clock_reads[0] == 4 * measured                           # two around the transfer, two the bookkeeping


def test_the_simulated_receivers_writer_counts_its_cpu_not_its_waits():
    from ahrsd.drivers.gnss.scenario import ScenarioGnssReceiver

    rx = ScenarioGnssReceiver("boat", chip_clock=lambda: 0.0)
    calls = [0]

    def write_due() -> float:        # a fix's work: 2 ms of CPU, then 3 ms of waiting (a write to the pty)
        calls[0] += 1
        _spin(0.002)
        time.sleep(0.003)
        return 0.0

    rx.write_due = write_due
    try:
        t0 = time.monotonic()
        rx.start()
        deadline = time.monotonic() + 60        # by count, not by a wall window (6 calls in 0.3 s at load 16, ci24)
        while calls[0] < 12 and time.monotonic() < deadline:
            time.sleep(0.01)
        rx._stop.set()
        rx._thread.join(5.0)
        elapsed = time.monotonic() - t0
    finally:
        rx.close()
    n = calls[0]
    c = rx.counters()
    assert n >= 10
    # thread CPU: the spins (less the last call's, which may not be counted yet) and not the sleeps
    assert (n - 1) * 0.002 <= c["writer_cpu_s"] < n * 0.002 + 0.02 < n * 0.005
    assert (n - 1) * 0.005 <= c["writer_wall_s"] <= elapsed
