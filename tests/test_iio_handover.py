"""The kernel IIO path's hand-over (drivers.threaded_source `_read_on_deadlines`, `HandoverPlan`): the reader thread
reads the kernel's buffer and hands its block over when the daemon's next output falls due (told through
`hand_over_by`), or at the latest HANDOVER_MAX_S after the last hand-over, and makes `ready_fd` readable — the
contract of the reader process (drivers.process_source `_Handover`, tests/test_handover_on_due.py).

The plan is checked with worked times; the daemon's reader (SampleReader, its `ready_fd` and output schedule) with
the plan on a virtual clock (tests/support/virtual_time_loop.py), the kernel writing a record every 1/819.2 s and
the reader thread's read a callback at the plan's time; the thread itself with counts, never with a time: every
wait is bounded by a margin of seconds that holds on a loaded machine."""

from __future__ import annotations

import asyncio
import math
import select
from types import SimpleNamespace

import numpy as np
import pytest

from ahrsd.calibration.models import Calibration
from ahrsd.core.sample import SampleFlags
from ahrsd.core.sample_block import SampleBlock
from ahrsd.daemon.counters import ServiceCounters
from ahrsd.daemon.health import Health
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.outputs import OutputSchedule
from ahrsd.daemon.pipeline import Pipeline
from ahrsd.daemon.sample_reader import ReaderOutputs, SampleListeners, SampleReader
from ahrsd.drivers import threaded_source
from ahrsd.drivers.errors import BusError
from ahrsd.drivers.source_interface import LiveSource
from ahrsd.drivers.iio_source import READ_AFTER_EDGE_S, IioSource, next_edge_s
from ahrsd.drivers.threaded_source import HANDOVER_MAX_S, HandoverPlan, ThreadedSource
from support.stub_estimator import StubEstimator
from support.virtual_time_loop import VirtualTimeLoop

RATE_HZ = 819.2
PERIOD_S = 1.0 / RATE_HZ
MARGIN_S = 10.0            # the longest a thread's wake may take on a loaded machine: never reached when it works


# -- the plan, worked by hand ----------------------------------------------------------------------------------------

def test_the_plan_reads_at_the_deadline_once_and_else_every_max_after_the_last():
    plan = HandoverPlan(0.025)
    assert plan.next_read_s() == -math.inf                  # no read yet: read now
    assert plan.read_at(10.0) is False
    assert plan.next_read_s() == 10.025                     # nothing told: 25 ms after the last read
    plan.due_s = 10.012
    assert plan.next_read_s() == 10.012                     # the daemon's output falls due first
    assert plan.read_at(10.0121) is True                    # a read that serves it
    assert plan.next_read_s() == pytest.approx(10.0371)     # served: the same deadline does not count again
    plan.due_s = 10.2                                       # a deadline later than the latest hand-over
    assert plan.next_read_s() == pytest.approx(10.0371)
    assert plan.read_at(10.0371) is False                   # the latest-by read does not serve it
    plan.due_s = 10.03                                      # told a deadline already past: read now
    assert plan.next_read_s() == 10.03 and plan.read_at(10.04) is True


# -- the daemon's reader with the plan, on a virtual clock -----------------------------------------------------------

GCS_RATES_HZ = {mavlink.MAVLINK_MSG_ID_ATTITUDE: 50.0, mavlink.MAVLINK_MSG_ID_VISION_POSITION_ESTIMATE: 30.0,
                mavlink.MAVLINK_MSG_ID_HIGHRES_IMU: 10.0, mavlink.MAVLINK_MSG_ID_SYS_STATUS: 1.0}
RUN_S = 5.0
THREAD_WAKE_S = 0.0002     # the reader thread's read and hand-over take this long (shorter than a period)


class _KernelAndReader(LiveSource):
    """The kernel's buffer (a record every period, from the loop's start), the reader thread (a read at the plan's
    time, its block on an eventfd-like pipe) and the daemon's end (poll, hand_over_by)."""

    sample_rate_hz = RATE_HZ
    per_sample = False
    handover_max_s = HANDOVER_MAX_S

    def __init__(self, loop: VirtualTimeLoop):
        import os

        self.os = os
        self.loop, self.t0 = loop, loop.time()
        self.plan = HandoverPlan(HANDOVER_MAX_S)
        self.plan.read_at(self.t0)
        self.ready_fd, self._w = os.pipe()
        os.set_blocking(self.ready_fd, False)
        self.handed: list[list[float]] = []        # blocks handed over, not yet polled
        self.reads: list[tuple[float, bool]] = []   # (loop time, on the daemon's deadline)
        self._k_read = 0                           # records taken from the kernel's buffer
        self._timer = None
        self._arm()

    def _arm(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
        target = self.plan.next_read_s()
        if target == self.plan.due_s:            # a deadline: read at its first record (ThreadedSource, IioSource)
            target = next_edge_s(target, self.t0, PERIOD_S) + READ_AFTER_EDGE_S
        self._timer = self.loop.call_at(max(self.loop.time(), target), self._read)

    def _read(self) -> None:
        now = self.loop.time()
        on_due = self.plan.read_at(now)
        newest = math.floor((now - self.t0) / PERIOD_S + 1e-9)       # the kernel's records so far
        block = [self.t0 + k * PERIOD_S for k in range(self._k_read, newest + 1)]
        self._k_read = newest + 1
        self.reads.append((now, on_due))
        assert len(self.reads) <= 1000 * RUN_S, "the reader reads without end"     # a wrong read time: fail, not hang
        if block:
            self.loop.call_at(now + THREAD_WAKE_S, self._hand_over, block)
        self._timer = None
        self._arm()

    def _hand_over(self, block) -> None:
        self.handed.append(block)
        self.os.write(self._w, b"x")
        # the virtual loop looks at descriptors after moving its clock to the next timer, unless a callback is
        # ready: one queued makes it look now, at the hand-over's time (as the eventfd wakes the real loop)
        self.loop.call_soon(lambda: None)

    def hand_over_by(self, t: float) -> None:
        self.plan.due_s = t
        self._arm()                                 # the thread re-plans (ThreadedSource: `told`)

    def poll(self):
        try:
            self.os.read(self.ready_fd, 4096)
        except BlockingIOError:
            pass
        blocks, self.handed = self.handed, []
        t = [x for b in blocks for x in b]
        n = len(t)
        return SampleBlock(t, np.tile([0.0, 0, 0, 0, 0, -9.8, 20, 0, 40], (n, 1)), [25.0] * n, [5.0] * n,
                           [int(SampleFlags.NEW_DATA)] * n, [0] * n, [round((x - self.t0) / PERIOD_S) for x in t])

    def counters(self):
        return {}

    def close(self):
        self.os.close(self.ready_fd)
        self.os.close(self._w)


def _run_reader(rates_hz):
    loop = VirtualTimeLoop()
    source = _KernelAndReader(loop)
    schedule = OutputSchedule(rates_hz)
    sent: list[tuple[float, float | None]] = []   # (loop time, newest sample's time) of each output sent
    box = []

    def publish(now):
        for _mid in schedule.due(now):
            last = box[0].pipeline.last_sample
            sent.append((now, None if last is None else last.t_s))

    reader = SampleReader(source, Pipeline(StubEstimator(), Calibration.identity()), Health(stale_timeout_s=0.1),
                          ServiceCounters(), SampleListeners(),
                          ReaderOutputs(publish=publish, statustext=lambda sev, text: None, heading_reset=lambda: None,
                                        ready=lambda: None, next_due=lambda: schedule.next_due),
                          poll_hz=200.0)
    box.append(reader)
    seen: list[int] = []
    reader.listeners.add(lambda s, e: seen.append(s.counter))

    task = loop.create_task(reader.run(loop))
    loop.call_at(loop.time() + RUN_S, task.cancel)          # the daemon stops after RUN_S of loop time
    try:
        loop.run_until_complete(asyncio.gather(task, return_exceptions=True))
    finally:
        loop.close()
        source.close()
    assert reader.done.cancelled()                 # cancelled at the end, not ended by an error
    return source, reader, sent, seen


def test_the_daemon_wakes_once_an_output_due_and_sends_each_with_the_newest_record():
    source, reader, sent, seen = _run_reader(GCS_RATES_HZ)
    # every record the kernel wrote reaches the daemon, in order, none twice
    assert seen == list(range(len(seen))) and len(seen) >= (RUN_S - 0.05) * RATE_HZ
    # the deadlines: ATTITUDE 50/s, VPE 30/s, HIGHRES 10/s, SYS_STATUS 1/s on one schedule; their distinct times are
    # the union of the 50 and 30 Hz grids (10 and 1 Hz fall on the 50 Hz one): 50 + 30 − 10 (the common 10 Hz) = 70/s
    on_due = sum(1 for _t, due in source.reads if due)
    assert 69 * RUN_S <= on_due <= 70 * RUN_S + 2
    # no read beyond those and the latest-by ones: two deadlines never 25 ms apart on these grids, so none
    assert len(source.reads) - on_due <= 2
    # the daemon's wakes: one a hand-over, and its first polls on the 5 ms tick until the first hand-over (25 ms
    # in at the latest: the tick at 20 ms serves the first deadline, told at 20 ms, before the read just after it);
    # the stand-in tick, 75 ms away at least, never needed after
    assert reader.counters.wakes <= len(source.reads) + 6
    # each output goes out with the first record from its deadline on: the read is READ_AFTER_EDGE_S after that
    # record's edge, the hand-over THREAD_WAKE_S later (a read at the deadline itself: up to a period older)
    lag = [now - newest for now, newest in sent[5:]]
    assert max(lag) <= READ_AFTER_EDGE_S + THREAD_WAKE_S + 1e-9


# -- the thread itself: counts ---------------------------------------------------------------------------------------

class _Buffer(LiveSource):
    """A block source standing in for the kernel's buffer: `pending` samples are there to take (the test adds them)."""

    description = "a block source"
    sample_rate_hz = RATE_HZ
    per_sample = False

    def __init__(self):
        self.k = 0
        self.pending = 0
        self.reads = 0
        self.arriving = 0          # records the kernel writes while a reader waits for the next one
        self.waits_for_next = 0
        self.base_s = 0.0          # the time stamp of record 0 (records k * PERIOD_S later)
        self.readable_s = 0.0      # how long after a time its first sample can be read (readable_after)
        self.fails_after_wait = False   # the read after a wait for the next record fails (the device gone)

    def readable_after(self, t: float) -> float:
        return t + self.readable_s

    def wait(self, timeout_s: float, paced: bool = True) -> bool:
        if not paced:
            self.waits_for_next += 1
            self.pending += self.arriving
            self.arriving = 0
            if self.fails_after_wait:
                self.pending = -1
        return self.pending != 0

    def poll(self) -> SampleBlock:
        self.reads += 1
        if self.pending < 0:
            self.pending = 0
            raise BusError("the device ended the stream")
        n, self.pending = self.pending, 0
        ks = list(range(self.k, self.k + n))
        self.k += n
        return SampleBlock([self.base_s + k * PERIOD_S for k in ks], np.zeros((n, 9)), [25.0] * n, [5.0] * n,
                           [int(SampleFlags.NEW_DATA)] * n, [0] * n, ks)

    def counters(self):
        return {}

    def close(self):
        pass


def _readable(fd: int, timeout_s: float) -> bool:
    return bool(select.select([fd], [], [], timeout_s)[0])


def _wait_for(pred, timeout_s: float = MARGIN_S) -> bool:
    end = _now() + timeout_s
    while not pred() and _now() < end:
        select.select([], [], [], 0.002)
    return pred()


def _now() -> float:
    import time

    return time.monotonic()


def test_the_reader_thread_hands_over_on_the_deadline_told_and_wakes_the_daemon(monkeypatch):
    """With the latest-by hand-over pushed out of reach (1000 s), a block is handed over only because the daemon
    told a deadline: the thread, waiting for 1000 s, is woken by `hand_over_by`, reads at the deadline, hands the
    block over and makes ready_fd readable; poll() takes the block and clears it."""
    monkeypatch.setattr(threaded_source, "HANDOVER_MAX_S", 1000.0)
    inner = _Buffer()
    src = ThreadedSource(inner, realtime=False, switch_interval_s=None)
    try:
        assert src.ready_fd is not None and src.handover_max_s == 1000.0
        assert len(src.poll()) == 0                        # starts the thread; nothing read yet
        inner.pending = 12
        assert _wait_for(lambda: src._waiting_until > _now() + 100)   # the thread waits for the latest-by read
        src.hand_over_by(_now())                           # an output falls due now
        assert _readable(src.ready_fd, MARGIN_S)
        block = src.poll()
        assert list(block.counter) == list(range(12)) and not _readable(src.ready_fd, 0.0)
        assert _wait_for(lambda: src._waiting_until > _now() + 100)
        src.hand_over_by(src._plan.served_s)               # the deadline served, told again: no read for it
        assert src._waiting_until > _now() + 100
        for expected_on_due in (2, 3):                     # every deadline told is served once
            inner.pending = 5
            assert _wait_for(lambda: src._waiting_until > _now() + 100)
            src.hand_over_by(_now() + 0.001)
            assert _readable(src.ready_fd, MARGIN_S)
            assert len(src.poll()) == 5
            assert src.stats["handovers_on_due"] == expected_on_due
        assert src.stats["handovers"] == 3 and src.stats["handed_over"] == 22
    finally:
        src.close()
    assert src.ready_fd is None


def test_a_deadline_with_no_record_waiting_is_served_with_the_next_record(monkeypatch):
    """A latest-by read just before the deadline took every record: the read at the deadline finds none, so the reader
    waits (unpaced) for the next record and hands it over, rather than leaving the output to the next hand-over."""
    monkeypatch.setattr(threaded_source, "HANDOVER_MAX_S", 1000.0)
    inner = _Buffer()
    src = ThreadedSource(inner, realtime=False, switch_interval_s=None)
    try:
        src.poll()
        assert _wait_for(lambda: src._waiting_until > _now() + 100)
        inner.arriving = 1                                 # nothing waiting; one record comes after the deadline
        src.hand_over_by(_now())
        assert _readable(src.ready_fd, MARGIN_S)
        assert list(src.poll().counter) == [0] and inner.waits_for_next == 1
        assert src.stats["handovers_on_due"] == 1
    finally:
        src.close()


def test_a_full_hand_over_buffer_drops_what_does_not_fit_and_flags_the_next_sample():
    """The daemon stalled: blocks beyond the buffer's capacity are dropped and counted, and the first sample handed
    over after them carries GAP_BEFORE (the pipeline counts the loss from the indices)."""
    inner = _Buffer()
    src = ThreadedSource(inner, realtime=False, switch_interval_s=None, capacity_samples=30)
    try:
        src.poll()
        for n in (20, 20, 20):                             # 20 fit, 10 of the next, then none: 30 dropped
            inner.pending = n
            src.hand_over_by(_now())
            assert _wait_for(lambda: inner.pending == 0 and src.stats["reads"] > 0 and src._waiting_until != math.inf)
        assert _wait_for(lambda: src.stats["handed_over"] + src.stats["handover_dropped"] == 60)
        first = src.poll()
        assert list(first.counter) == list(range(30)) and src.stats["handover_dropped"] == 30
        inner.pending = 4
        src.hand_over_by(_now())
        assert _readable(src.ready_fd, MARGIN_S) and _wait_for(lambda: src.stats["handed_over"] == 34)
        after = src.poll()
        assert list(after.counter) == [60, 61, 62, 63]
        assert [bool(f & SampleFlags.GAP_BEFORE) for f in after.flags] == [True, False, False, False]
    finally:
        src.close()


def test_a_per_sample_reader_has_no_ready_fd_and_ignores_deadlines():
    src = ThreadedSource(SimpleNamespace(per_sample=True, description="chip", sample_rate_hz=RATE_HZ), realtime=False,
                         switch_interval_s=None)
    assert src.ready_fd is None and src.handover_max_s == 0.0
    src.hand_over_by(1.0)
    assert src._timer is None and src._waiting_until == math.inf


# -- session 42: the read for a deadline waits for the chip's first sample at or after it -----------------------------

def _waiting_reader(monkeypatch):
    """A started reader thread on a _Buffer, waiting for its latest-by read 1000 s on: only a deadline told makes it
    read."""
    monkeypatch.setattr(threaded_source, "HANDOVER_MAX_S", 1000.0)
    inner = _Buffer()
    src = ThreadedSource(inner, realtime=False, switch_interval_s=None)
    src.poll()
    assert _wait_for(lambda: src._waiting_until > _now() + 900)
    return inner, src


def test_the_next_edge_by_worked_times():
    # edges every 1 ms from 10.000 s
    assert next_edge_s(10.0035, 10.0, 0.001) == pytest.approx(10.004)
    assert next_edge_s(10.004, 10.0, 0.001) == pytest.approx(10.004)          # on an edge: that edge
    assert next_edge_s(10.0040005, 10.0, 0.001) == pytest.approx(10.004)      # within 1 µs past it: that edge
    assert next_edge_s(10.0041, 10.0, 0.001) == pytest.approx(10.005)
    assert next_edge_s(9.9, 10.0, 0.001) == 10.0                              # before the last edge: that one


def test_an_iio_source_reads_a_deadline_at_the_next_edge_plus_the_burst_read():
    src = object.__new__(IioSource)                        # the edge rule only: no device
    src._last_ns, src._period_ns = None, 1e9 / RATE_HZ
    assert src.readable_after(5.0) == 5.0                  # no record yet: at the deadline
    src._last_ns = 5_000_000_000                           # the last record was stamped 5.000 s
    # a deadline 3.5 periods on: the 4th edge, 4 / 819.2 s = 4.8828125 ms, and the driver's burst read
    assert src.readable_after(5.0 + 3.5 / RATE_HZ) == pytest.approx(5.0 + 4 / RATE_HZ + READ_AFTER_EDGE_S)
    assert READ_AFTER_EDGE_S == pytest.approx(26 * 8 / 1e6, abs=0.0001)   # 26 bytes at 1 MHz, with the wake


def test_the_reader_thread_waits_for_the_first_sample_after_the_deadline_not_the_deadline(monkeypatch):
    """The thread told a deadline waits until the source says the deadline's first sample can be read
    (`readable_after`), not until the deadline itself: with that 500 s away it waits and does not read."""
    monkeypatch.setattr(threaded_source, "HANDOVER_MAX_S", 1000.0)
    inner = _Buffer()
    src = ThreadedSource(inner, realtime=False, switch_interval_s=None)
    try:
        src.poll()
        assert _wait_for(lambda: src._waiting_until > _now() + 900)   # the latest-by read, 1000 s on
        reads = inner.reads
        inner.readable_s = 500.0
        due = _now()
        src.hand_over_by(due)
        assert _wait_for(lambda: src._waiting_until == due + 500.0)
        assert inner.reads == reads                                # not read at the deadline
        inner.readable_s, inner.pending = 0.0, 3
        src.hand_over_by(_now())                                   # one that can be read now: read and handed over
        assert _readable(src.ready_fd, MARGIN_S) and len(src.poll()) == 3
    finally:
        src.close()


def test_a_deadline_read_that_finds_only_older_samples_waits_for_the_next_one(monkeypatch):
    """Records waiting, but all stamped before the deadline (the chip's record for it not yet there): the reader
    waits for the next record and hands the lot over as one block; records from the deadline on need no wait."""
    inner, src = _waiting_reader(monkeypatch)
    try:
        inner.pending, inner.arriving = 3, 1               # stamped at 0 s: before any deadline
        src.hand_over_by(_now())
        assert _readable(src.ready_fd, MARGIN_S)
        assert list(src.poll().counter) == [0, 1, 2, 3] and inner.waits_for_next == 1
        assert src.stats["handovers"] == 1 and src.stats["handovers_on_due"] == 1
        assert _wait_for(lambda: src._waiting_until > _now() + 900)
        inner.base_s = _now() + 1000.0                     # stamped after the deadline: taken as they are
        inner.pending, inner.arriving = 2, 1
        src.hand_over_by(_now())
        assert _readable(src.ready_fd, MARGIN_S)
        assert list(src.poll().counter) == [4, 5] and inner.waits_for_next == 1
    finally:
        src.close()


def test_the_reader_reads_a_deadline_when_its_first_sample_can_be_read_and_else_at_the_latest():
    """The block reader's next read time (`_next_read_s`, worked times, no thread): a deadline told and not served is
    read at the source's `readable_after` of it; a served one leaves the latest-by read."""
    inner = _Buffer()
    inner.readable_s = 0.0009
    src = ThreadedSource(inner, realtime=False, switch_interval_s=None)
    try:
        plan = src._plan
        plan.read_at(100.0)                                # latest-by at 100.025
        plan.due_s = 100.010
        assert src._next_read_s() == pytest.approx(100.0109)
        assert plan.read_at(100.0109) is True              # served
        assert src._next_read_s() == pytest.approx(100.0359)
    finally:
        src.close()


def test_samples_read_before_a_failed_read_for_the_next_record_are_handed_over(monkeypatch):
    """A deadline's read finds only older samples and waits for the next record, whose read fails (the device gone):
    the samples already read still reach the daemon (a sample the source counted is never dropped here)."""
    inner, src = _waiting_reader(monkeypatch)
    try:
        inner.pending, inner.fails_after_wait = 3, True
        src.hand_over_by(_now())
        assert _readable(src.ready_fd, MARGIN_S)
        assert list(src.poll().counter) == [0, 1, 2] and src.stats["read_failures"] == 1
    finally:
        src.close()
