"""drivers.data_ready: reads paced by the chip's DIO1 data-ready edges, against host-timer pacing, on a chip whose
oscillator drifts ±50 ppm from the host clock (stepped clocks: no wall-clock time anywhere)."""

from __future__ import annotations

import pytest

from ahrsd.drivers import registers as R
from ahrsd.drivers.adis16405 import Adis16405
from ahrsd.drivers.chip_source import ChipSource
from ahrsd.drivers.data_ready import DataReadyTimer, parse_gpio
from ahrsd.drivers.ground_truth import BurstIndexTap
from ahrsd.drivers.sample_timer import StallAwareSampleTimer
from ahrsd.drivers.simulated import SimulatedAdis16405, SimulatedDataReadyLine
from ahrsd.drivers.sim_clock import ChipClock
from support.stepped_clock import ManualClock

RATE_HZ = 819.2
PERIOD_S = 1 / RATE_HZ
READ_LATENCY_S = 20e-6          # edge (or timer) to the start of the transfer


class HostClock(ManualClock):
    def sleep_until(self, t: float) -> None:
        self.t = max(self.t, t + READ_LATENCY_S)


class DriftingChipClock(ChipClock):
    """The chip's oscillator, `ppm` fast (or slow) against the host clock."""

    def __init__(self, host: HostClock, ppm: float):
        self.host, self.scale, self.t0 = host, 1.0 + ppm * 1e-6, host()

    def __call__(self) -> float:
        return self.t0 + (self.host() - self.t0) * self.scale

    def to_host(self, t: float) -> float:
        return self.t0 + (t - self.t0) / self.scale

    def sleep(self, s: float) -> None:
        self.host.sleep(s / self.scale)


def drifting_chip(ppm: float, msc_ctrl: int | None = None):
    host = HostClock()
    chip = SimulatedAdis16405("static", seed=4, clock=DriftingChipClock(host, ppm))
    if msc_ctrl is not None:
        chip._regs[R.MSC_CTRL >> 1] = msc_ctrl            # what the chip's flash held
    return host, chip, BurstIndexTap(chip)


def run(src, tap, host, seconds: float, wait=None) -> dict:
    """Read for `seconds` of host time; compare every delivered index step with the chip's own."""
    end = host.t + seconds
    prev = None
    out = {"delivered": 0, "index_errors": 0, "stamp_error_max_s": 0.0}
    chip = tap.chip
    while host.t < end:
        if wait is not None:
            if not wait(0.1):
                continue
        else:
            host.t = max(host.t, src.next_read_time())
        s = src.read_one(host.t)
        if s is None:
            continue
        out["delivered"] += 1
        truth_ready = chip._clock.to_host(chip.ready_clock_time(tap.burst_index))
        out["stamp_error_max_s"] = max(out["stamp_error_max_s"], abs(s.t_s - truth_ready))
        if prev is not None and s.counter - prev[0] != tap.burst_index - prev[1]:
            out["index_errors"] += 1
        prev = (s.counter, tap.burst_index)
    out.update(chip_lost=chip.stats["samples_lost"], counted_lost=src.lost_samples, stale_reads=src.stale_reads)
    return out


def timer_paced(ppm: float, seconds: float) -> dict:
    host, chip, tap = drifting_chip(ppm)
    driver = Adis16405(tap)
    driver.start(self_test=False)
    src = ChipSource(driver, tap, "timer", clock=host, timer=StallAwareSampleTimer(PERIOD_S))
    return run(src, tap, host, seconds)


def edge_paced(ppm: float, seconds: float, msc_ctrl: int | None = 0x0000) -> dict:
    host, chip, tap = drifting_chip(ppm, msc_ctrl)
    driver = Adis16405(tap, data_ready=True)          # start() routes data-ready to DIO1
    driver.start(self_test=False)
    line = SimulatedDataReadyLine(chip, host_clock=host)
    timer = DataReadyTimer(line, PERIOD_S)
    src = ChipSource(driver, tap, "edges", clock=host, timer=timer)
    out = run(src, tap, host, seconds, wait=timer.wait)
    out["msc_ctrl"] = chip._regs[R.MSC_CTRL >> 1]
    return out


@pytest.mark.parametrize("ppm", [50.0, -50.0])
def test_data_ready_pacing_follows_a_drifting_chip_exactly(ppm):
    r = edge_paced(ppm, 30.0)
    assert r["msc_ctrl"] & 0x07 == 0x06                   # DATA_RDY_EN | POL_HIGH, DIO1 (flash held 0x0000)
    assert r["delivered"] >= 30.0 * RATE_HZ * (1 - 1e-4) - 2
    assert r["chip_lost"] == r["counted_lost"] == 0
    assert r["stale_reads"] == 0 and r["index_errors"] == 0
    assert r["stamp_error_max_s"] < 1e-6                  # the edge's own time


@pytest.mark.parametrize("ppm", [50.0, -50.0])
def test_the_host_timer_fallback_re_reads_samples_on_a_drifting_chip(ppm):
    """The timer re-learns the chip's phase from reads that come too early: each finds the previous sample
    again (ND clear, a duplicate the source drops and counts). It loses nothing here (an ideal reader), but its
    time stamps are the timer's bracket, not the chip's edge."""
    r = timer_paced(ppm, 30.0)
    assert r["stale_reads"] > 0.002 * r["delivered"]
    assert r["chip_lost"] == r["counted_lost"]
    assert r["stamp_error_max_s"] > 10 * edge_paced(ppm, 5.0)["stamp_error_max_s"]


@pytest.mark.parametrize("ppm", [50.0, -50.0])
def test_a_fixed_host_period_slips_samples_on_a_drifting_chip(ppm):
    """Reads every nominal period on the host clock (no phase tracking): after 30 s at ±50 ppm the chip is
    1.23 samples ahead or behind — gaps (fast chip) or duplicates (slow chip), 1 or 2 by the start phase."""
    host, chip, tap = drifting_chip(ppm)
    driver = Adis16405(tap)
    driver.start(self_test=False)
    t0 = host.t + 0.5 * PERIOD_S
    stale = 0
    for k in range(int(30.0 * RATE_HZ)):
        host.t = t0 + k * PERIOD_S
        s = driver.read_sample()
        stale += bool(s.flags & s.flags.STALE)
    if ppm > 0:
        assert chip.stats["samples_lost"] in (1, 2) and stale == 0     # 30 s × 50e-6 × 819.2 = 1.23
    else:
        assert stale in (1, 2) and chip.stats["samples_lost"] == 0


def test_no_edges_unless_msc_ctrl_routes_data_ready_to_dio1():
    host, chip, tap = drifting_chip(0.0, msc_ctrl=0x0000)
    line = SimulatedDataReadyLine(chip, host_clock=host)
    assert not line.wait_edge_events(0.01)
    chip._regs[R.MSC_CTRL >> 1] = 0x0007                 # enabled, but on DIO2
    assert not line.wait_edge_events(0.01)
    driver = Adis16405(tap)
    driver.enable_data_ready()
    assert chip._regs[R.MSC_CTRL >> 1] == 0x0006
    assert line.wait_edge_events(0.01)
    events = line.read_edge_events()
    assert [e.line_seqno for e in events] == [1]


def test_edges_the_reader_missed_are_counted_from_the_sequence_numbers():
    host, chip, tap = drifting_chip(0.0)
    driver = Adis16405(tap, data_ready=True)
    driver.start(self_test=False)
    line = SimulatedDataReadyLine(chip, host_clock=host)
    timer = DataReadyTimer(line, PERIOD_S)
    src = ChipSource(driver, tap, "edges", clock=host, timer=timer)
    got = []
    for _ in range(10):
        assert timer.wait(0.1)
        got.append(src.read_one(host.t))
    host.t += 40 * PERIOD_S                               # the reader stalled: 40 edges, 16 kept by the kernel
    assert timer.wait(0.1)
    got.append(src.read_one(host.t))
    assert got[-1].counter - got[-2].counter - 1 == src.lost_samples == chip.stats["samples_lost"] >= 39
    assert got[-1].flags & got[-1].flags.GAP_BEFORE


def test_gpio_spec():
    assert parse_gpio("gpiochip0:25") == ("/dev/gpiochip0", 25)
    assert parse_gpio("/dev/gpiochip4:17") == ("/dev/gpiochip4", 17)
    with pytest.raises(ValueError):
        parse_gpio("25")
