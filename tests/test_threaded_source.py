"""drivers.threaded_source: the chip read in a dedicated thread, handed to the event loop in blocks.

All on a stepped clock (tests/stepped_clock.py): the simulated chip produces samples on it, the reader thread
sleeps on it, and the event loop's handler that "sleeps 50 ms" advances it by 50 ms without polling."""

from __future__ import annotations

import asyncio

import pytest

from ahrsd.core.sample import SampleFlags
from ahrsd.drivers.errors import BusError
from ahrsd.drivers.simulated import SimulatedAdis16405
from ahrsd.drivers.source import start_chip_source
from ahrsd.drivers.threaded_source import ThreadedSource

from support.stepped_clock import SteppedClock

PERIOD_S = 1 / 819.2


def chip_and_source(clock):
    chip = SimulatedAdis16405("static", seed=3, clock=clock)
    return chip, start_chip_source(chip, "test chip", clock=clock, self_test=False)


def gap_samples(samples) -> int:
    """Samples missing between the delivered ones, counted as the pipeline does (GAP_BEFORE + index jump)."""
    lost = 0
    for a, b in zip(samples, samples[1:]):
        assert b.counter > a.counter
        if b.counter != a.counter + 1:
            assert b.flags & SampleFlags.GAP_BEFORE
            lost += b.counter - a.counter - 1
    return lost


async def starved_loop(clock, poll, stalls: int, got: list) -> None:
    """An event loop whose poll runs every 5 ms, and every 10th iteration a handler holds it for 50 ms."""
    for i in range(10 * stalls):
        got.extend(poll())
        clock.run_for(0.005)                  # the loop idles 5 ms
        if i % 10 == 5:
            clock.run_for(0.050)              # a handler sleeping 50 ms: no poll, no other task
        await asyncio.sleep(0)
    clock.run_for(0.005)
    got.extend(poll())


def read_through_a_starved_loop(src, clock, stalls: int) -> list:
    """Start the reader, run `starved_loop` with it, stop both; the samples the loop took."""
    src.start()
    got: list = []
    try:
        asyncio.run(starved_loop(clock, src.poll, stalls=stalls, got=got))
    finally:
        clock.close()
        src.close()
    return got


def test_a_starved_event_loop_loses_no_sample():
    clock = SteppedClock()
    chip, inner = chip_and_source(clock)
    src = ThreadedSource(inner, clock=clock, sleep_until=clock.sleep_until, realtime=False)
    got = read_through_a_starved_loop(src, clock, stalls=8)
    produced_while_read = got[-1].counter - got[0].counter + 1
    assert produced_while_read > 8 * 0.1 / PERIOD_S * 0.95           # 8 × 100 ms of chip time went by
    assert len(got) == produced_while_read
    assert gap_samples(got) == 0
    assert chip.stats["samples_lost"] == 0                           # the chip's own truth
    assert src.stats["handover_max_backlog"] >= int(0.05 / PERIOD_S)  # the stalls really held samples back


def test_the_same_stall_on_the_event_loop_reader_loses_samples():
    """The contrast: reading on the loop (a read per poll, as a loop-bound reader would) loses each stall."""
    clock = SteppedClock()
    chip, inner = chip_and_source(clock)
    got: list = []

    def poll_on_the_loop():
        out = []
        for _ in range(8):                    # as many reads as are due, right now
            s = inner.read_one(clock())
            if s is not None:
                out.append(s)
        return out

    async def loop_reader():
        for i in range(40):
            got.extend(poll_on_the_loop())
            clock.t += 0.001
            if i % 10 == 5:
                clock.t += 0.050
            await asyncio.sleep(0)

    asyncio.run(loop_reader())
    assert gap_samples(got) >= 4 * 0.045 / PERIOD_S
    assert chip.stats["samples_lost"] == gap_samples(got)


def test_a_full_handover_buffer_is_counted_as_lost_samples():
    clock = SteppedClock()
    chip, inner = chip_and_source(clock)
    src = ThreadedSource(inner, clock=clock, sleep_until=clock.sleep_until, realtime=False, capacity_samples=16)
    src.start()
    got: list = []
    try:
        got.extend(src.poll())
        clock.run_for(0.010)
        got.extend(src.poll())
        clock.run_for(0.100)                  # 82 samples, 16 fit
        got.extend(src.poll())
        clock.run_for(0.010)
        got.extend(src.poll())
    finally:
        clock.close()
        src.close()
    dropped = src.stats["handover_dropped"]
    assert dropped >= 0.1 / PERIOD_S - 16 - 2
    assert gap_samples(got) == dropped
    assert chip.stats["samples_lost"] == 0                           # read from the chip, dropped here


def test_a_bus_failure_reaches_the_daemon_from_poll():
    clock = SteppedClock()
    chip, inner = chip_and_source(clock)
    src = ThreadedSource(inner, clock=clock, sleep_until=clock.sleep_until, realtime=False)
    src.start()
    try:
        clock.run_for(0.01)
        assert src.poll()
        chip.close()                          # the device node went away
        clock.run_for(0.01)
        with pytest.raises(BusError, match="closed"):
            src.poll()                        # (after what was read before the failure, if any)
            src.poll()
        assert src.counters()["reader_read_failures"] >= 1
    finally:
        clock.close()
        src.close()


@pytest.mark.parametrize("refused", ["", "Operation not permitted"])
def test_one_log_line_says_whether_the_reader_got_realtime_priority(caplog, refused):
    import logging

    clock = SteppedClock()
    chip, inner = chip_and_source(clock)
    src = ThreadedSource(inner, clock=clock, sleep_until=clock.sleep_until, request_priority=lambda: refused)
    caplog.set_level(logging.INFO, logger="ahrsd.drivers.threaded_source")
    read_through_a_starved_loop(src, clock, stalls=1)
    lines = [r for r in caplog.records if "real-time priority" in r.getMessage()]
    assert len(lines) == 1
    if refused:
        assert lines[0].levelname == "WARNING" and "NO real-time priority" in lines[0].getMessage()
        assert refused in lines[0].getMessage() and "LimitRTPRIO" in lines[0].getMessage()
    else:
        assert lines[0].levelname == "INFO" and "SCHED_FIFO 50" in lines[0].getMessage()
    assert src.counters()["reader_realtime_priority"] == (0 if refused else 1)


def test_a_wake_later_than_a_period_is_counted_with_its_lateness():
    """`reader_wakes_late` / `reader_wake_late_max_us` (run_stats): how often the reader woke (and had the
    GIL) after the chip's next sample was due, and by how much at worst; here one wake 3 periods late."""
    clock = SteppedClock()
    chip, inner = chip_and_source(clock)
    calls = [0]

    def sleep_until(t):
        calls[0] += 1
        clock.sleep_until(t + (3 * PERIOD_S if calls[0] == 50 else 0.0))

    src = ThreadedSource(inner, clock=clock, sleep_until=sleep_until, realtime=False)
    got = read_through_a_starved_loop(src, clock, stalls=1)
    c = src.counters()
    assert calls[0] > 50
    assert c["reader_wakes_late"] == 1
    assert 3 * PERIOD_S * 1e6 - 60 <= c["reader_wake_late_max_us"] <= 3 * PERIOD_S * 1e6 + 1
    assert gap_samples(got) == c["lost_samples_host"] >= 2         # the late wake lost the samples it slept past


def test_a_data_ready_stall_is_waited_out_in_half_periods_not_spun():
    """The chip's data-ready stalls for 100 samples (0.12 s): the timer keeps its phase, so its next read time
    stays in the past through the stall. The reader then re-reads every half period, sleeping in between; one
    that re-read at once would busy-loop at real-time priority for the whole stall (on this stepped clock it
    never sleeps again and the clock cannot advance: the run fails). After the stall every sample is read."""
    from ahrsd.drivers.faults import FaultKind, FaultPlan
    from ahrsd.drivers.sample_timer import StallAwareSampleTimer

    clock = SteppedClock(patience_s=3.0)
    plan = FaultPlan(seed=1)
    chip = SimulatedAdis16405("static", seed=3, clock=clock, faults=plan)
    inner = start_chip_source(chip, "test chip", clock=clock, self_test=False)
    inner.timer = StallAwareSampleTimer(inner.timer.period_s)     # the daemon's (drivers.reconnecting)
    first = chip.sample_index + 60
    plan.add(FaultKind.STALL, start_sample=first, stop_sample=first + 100)
    src = ThreadedSource(inner, clock=clock, sleep_until=clock.sleep_until, realtime=False)
    got = read_through_a_starved_loop(src, clock, stalls=4)                # 0.4 s of chip time
    stall_s = 100 * PERIOD_S
    assert 0.8 * stall_s / (0.5 * PERIOD_S) <= src.stats["stale_rereads_spaced"] <= 1.1 * stall_s / (0.5 * PERIOD_S)
    assert len(got) > 100 and gap_samples(got[-100:]) == 0                    # the reads after it are whole


def test_a_timer_that_appears_after_the_start_paces_the_reads_from_then_on():
    """The chip's timer exists once the chip first started (drivers.reconnecting: a sensor down at start has
    none): the reader looks it up until it is there, and then waits on its data-ready edges for every read."""
    from types import SimpleNamespace

    class SensorUpAtTheThirdRead:
        per_sample = True
        description = "a chip down at start"
        sample_rate_hz = 819.2

        def __init__(self):
            self.timer, self.reads, self.waits = None, 0, 0

        def next_read_time(self) -> float:
            return 0.0                        # read at once (no sleeping in this test)

        def read_one(self, now):
            self.reads += 1
            if self.reads == 3:
                self.timer = SimpleNamespace(wait=self._wait, waits_for_edges=True)
            if self.reads == 10:
                src._stop.set()
            return None

        def _wait(self, timeout_s) -> bool:
            self.waits += 1
            return True

    inner = SensorUpAtTheThirdRead()
    src = ThreadedSource(inner, realtime=False, switch_interval_s=None)
    src._read_per_sample()
    assert inner.reads == 10 and inner.waits == 7       # every read after the one that brought the timer
