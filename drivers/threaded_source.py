"""A sensor read off the event loop: a per-sample source (drivers.chip_source / reconnecting / ground_truth) read
in a dedicated thread, or a block source that buffers on its own (drivers.iio_source: the kernel's buffer)
drained by one, the samples handed to the daemon in blocks through a bounded buffer (`poll()`, the block path a
recording uses), so a slow MAVLink peer, a log flush or a GNSS burst on the event loop never delays a read.

A block source is read when the daemon's next output falls due (`hand_over_by`) and at the latest HANDOVER_MAX_S
after the last hand-over (drivers.handover_plan, the reader process's contract too), its block handed over as columns
and the daemon woken through an eventfd (`ready_fd`), so the daemon wakes once an output due, not on its polling
tick, and the kernel's buffer is read once an output due, not every few ms (docs/daemon.md "Performance": what it
saves). The read for a deadline waits for the chip's first sample at or after it (`readable_after`: its data-ready
edge and the driver's burst read), so that output goes out with a sample just made.

What the GIL does to it (docs/drivers.md, measured with bench/reader_gil.py): the interpreter's switch
interval bounds how long this thread waits for the GIL while the event loop runs Python code; at 819.2 SPS the
chip keeps a sample for 1.22 ms, so the source lowers it to SWITCH_INTERVAL_S for the whole process while it
runs. Where the CPU is contended a process loses less (its own GIL): drivers.process_source runs this same
reader in a child process, the default for the real and the simulated chip.

The thread asks for SCHED_FIFO (`os.sched_setscheduler`) when the system allows it (root, CAP_SYS_NICE or an
RLIMIT_RTPRIO, e.g. systemd's `LimitRTPRIO=`); one log line says whether it got it (a warning when not: it then
runs at normal priority).

Loss accounting stays where it was: the inner source's SampleTimer (or the data-ready pacing, drivers.data_ready)
flags GAP_BEFORE on the first sample after lost ones. A sample the chip produced and the reader read but the
daemon did not take in time (the buffer full: the event loop stalled for seconds) is dropped here, counted
(`handover_dropped`) and the next sample handed over carries GAP_BEFORE, so the pipeline counts it from the
sample indices like any other loss.
"""

from __future__ import annotations

import functools
import logging
import math
import os
import sys
import threading
import time
from typing import Callable

import numpy as np

from ahrsd.core.sample import ImuSample, SampleFlags
from ahrsd.core.sample_block import SampleBlock
from ahrsd.drivers.errors import FrameError
from ahrsd.drivers.handover_plan import HANDOVER_MAX_S, HandoverPlan
from ahrsd.drivers.read_failures import ReadFailures
from ahrsd.drivers.source_interface import LiveSource, WaitingSource
from ahrsd.drivers.timerfd import TimerFd

log = logging.getLogger(__name__)

CAPACITY_SAMPLES = 8192            # about 10 s at 819.2 SPS: the longest event-loop stall without a loss
SWITCH_INTERVAL_S = 0.0002         # the GIL hand-over bound while a reader thread runs (default 0.005)
STALE_REREAD_PERIODS = 0.5        # after a stale read whose next read time is past, re-read this much later
FIFO_PRIORITY = 50                 # SCHED_FIFO priority of the reader (1..99; below the kernel's IRQ threads)
_GAP_BEFORE = int(SampleFlags.GAP_BEFORE)
# A block source read in the daemon's process (the kernel's IIO buffer) hands its block over as the reader process
# does (drivers.handover_plan: the daemon's next output deadline, at the latest HANDOVER_MAX_S after the last).


def _sleep_until(clock, t: float) -> None:
    dt = t - clock()
    if dt > 0:
        time.sleep(dt)


def request_realtime_priority(priority: int = FIFO_PRIORITY) -> str:
    """SCHED_FIFO for the calling thread (Linux: pid 0 is the calling thread): "" when granted, else why not."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (PermissionError, OSError, AttributeError) as exc:
        return str(exc) or type(exc).__name__
    return ""


def share_realtime_priority(pids: list[int], priority: int = FIFO_PRIORITY) -> str:
    """SCHED_FIFO `priority` for every thread of the processes `pids` (what the reader waits on: the simulated
    chip's block producer). A real-time reader that waits on a normal-priority process waits for whatever
    the scheduler runs before it: a priority inversion. "" when done, else why not."""
    for pid in pids:
        try:
            tids = [int(t) for t in os.listdir(f"/proc/{pid}/task")]
        except OSError:
            tids = [pid]
        for tid in tids:
            try:
                os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
            except ProcessLookupError:
                pass
            except (PermissionError, OSError, AttributeError) as exc:
                return str(exc) or type(exc).__name__
    return ""


def _helper_pids(inner) -> list[int]:
    """The processes the inner source's reads may wait on (a simulated chip's block producer)."""
    chip = inner.chip         # drivers.source_interface.SensorSource: None for a real sensor
    return [] if chip is None else list(chip.helper_pids())


def log_realtime_priority(who: str, refused: str, priority: int = FIFO_PRIORITY) -> None:
    """The one log line that says whether the sensor reader runs at real-time priority."""
    if refused:
        log.warning("%s: NO real-time priority (%s): running at normal priority, samples are lost whenever the "
                    "reader is not scheduled within a sample period. Allow SCHED_FIFO with root, CAP_SYS_NICE or "
                    "RLIMIT_RTPRIO (systemd: RestrictRealtime=no, LimitRTPRIO=%d; docs/drivers.md)",
                    who, refused, priority)
    else:
        log.info("%s: real-time priority SCHED_FIFO %d", who, priority)


class ThreadedSource(LiveSource):
    """`inner` (a started per-sample source) read in its own thread; `poll()` returns every sample read since the
    last call. Sensor failures reach the daemon as exceptions from `poll()` once the buffer is drained.

    clock: the host clock of the reads (the inner source's); sleep_until(t): wait until clock() ≥ t (a test's
        stepped clock). Pacing: when the inner source's timer waits for the chip's data-ready (`waits_for_edges`:
        drivers.data_ready.DataReadyTimer's `wait(timeout_s)`) each read follows an edge; otherwise the thread
        sleeps until the SampleTimer's next read time. realtime: the reader thread asks for SCHED_FIFO with
        `request_priority()` ("" granted, else why not; request_realtime_priority asks the kernel).
    """

    description: str
    sample_rate_hz: float
    per_sample = False
    monotonic_offset_s = 0.0
    chip = property(lambda self: self.inner.chip)
    bus = property(lambda self: self.inner.bus)       # a chip source's bus (bench/latency.py reads its clock)
    ready_fd: int | None = None          # a block source's eventfd, readable once a block was handed over
    handover_max_s = 0.0

    def __init__(self, inner, *, clock=time.monotonic, sleep_until=None,
                 capacity_samples: int = CAPACITY_SAMPLES, realtime: bool = True,
                 switch_interval_s: float | None = SWITCH_INTERVAL_S,
                 request_priority: Callable[[], str] = request_realtime_priority):
        if not (inner.per_sample or isinstance(inner, WaitingSource)):
            raise TypeError("ThreadedSource reads a per-sample source (read_one / next_read_time) or a block "
                            "source that can wait for data (wait(timeout_s) / poll())")
        self.inner = inner
        self.description = f"{inner.description}, read in a dedicated thread"
        self.sample_rate_hz = inner.sample_rate_hz
        self._clock = clock
        self._sleep_until = sleep_until or functools.partial(_sleep_until, clock)
        self._sleep_until_given = sleep_until     # None: the pacing sleeps with time.sleep itself
        self._capacity = int(capacity_samples)
        self._realtime = realtime
        self._request_priority = request_priority     # asks for SCHED_FIFO: "" granted, else why not
        self._switch_interval_s = switch_interval_s
        self._saved_switch_interval: float | None = None
        self._lock = threading.Lock()          # the hand-over buffer and the error
        self._inner_lock = threading.Lock()    # the inner source: a read, or counters() from the event loop
        # the hand-over buffer: samples (a per-sample source) or SampleBlocks (a block source), `_buffered` samples
        self._buf: list = []
        self._buffered = 0
        self._gap_pending = False
        self._error: Exception | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.stats = {"reads": 0, "corrupt_frames": 0, "read_failures": 0, "handover_dropped": 0,
                      "handover_max_backlog": 0, "realtime_priority": 0, "undelivered_at_close": 0,
                      "wakes_late": 0, "wake_late_max_us": 0, "helpers_realtime": 0, "handed_over": 0,
                      "wakes_late_quarter": 0, "read_us_max": 0, "stale_rereads_spaced": 0}
        self._last_delivered: int | None = None
        self.after_read = None     # called by the reader thread between reads (drivers.process_source's hand-over)
        self._plan = HandoverPlan(HANDOVER_MAX_S)
        self._waiting_until = math.inf           # when the block reader's timer expires (inf: it is not waiting)
        self._timer: TimerFd | None = None       # what the block reader waits on; hand_over_by moves it sooner
        if not inner.per_sample:
            # the daemon polls when this becomes readable (daemon.sample_reader `ready_fd`), not on a fixed tick
            self.ready_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
            self._timer = TimerFd()
            self.handover_max_s = HANDOVER_MAX_S
            self.stats.update({"handovers": 0, "handovers_on_due": 0})
        self.log_realtime = True   # log whether SCHED_FIFO was granted (a reader process reports it instead)
        self.realtime_refused: str | None = None   # "" granted, else why not (None: not asked)


    # -- the reader thread -------------------------------------------------------------------------------------

    def start(self) -> None:
        """Start the reader thread (the first `poll()` does it if nobody did: samples the chip produced while
        the daemon was still starting are not read, hence not lost — as with a reader on the event loop)."""
        if self._thread is not None:
            return
        if self._switch_interval_s is not None:
            self._saved_switch_interval = sys.getswitchinterval()
            sys.setswitchinterval(min(self._saved_switch_interval, self._switch_interval_s))
        self._thread = threading.Thread(target=self._run, name="ahrsd-sensor-reader", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        if self._realtime:
            self.realtime_refused = self._request_priority()
            self.stats["realtime_priority"] = int(not self.realtime_refused)
            if not self.realtime_refused:
                # the producer started before the reader asked; one started later (a rate change) is forked
                # by this thread and inherits its policy
                refused = share_realtime_priority(_helper_pids(self.inner))
                if refused:
                    log.warning("the simulated chip's block producer keeps normal priority (%s): the real-time "
                                "reader may wait on it", refused)
                self.stats["helpers_realtime"] = int(not refused)
            if self.log_realtime:
                log_realtime_priority("sensor reader thread", self.realtime_refused)
        if self.inner.per_sample:
            self._read_per_sample()
        elif self.after_read is not None:
            self._read_blocks()            # in a reader process: its own hand-over decides (drivers.process_source)
        else:
            self._read_on_deadlines()

    def _read_blocks(self) -> None:
        """A source that buffers on its own (the kernel's IIO buffer): wait for data, take every record."""
        failures = ReadFailures()
        inner, stop, after_read = self.inner, self._stop, self.after_read
        while not stop.is_set():
            if after_read is not None:
                after_read()
            try:
                if not inner.wait(0.1):
                    continue
                with self._inner_lock:
                    samples = inner.poll()
            except Exception as exc:  # noqa: BLE001 - BusError / OSError: the source re-opens on its own
                self._read_failed(exc, failures)
                continue
            self.stats["reads"] += 1
            failures.read_ok()
            for sample in samples:
                self._hand_over(sample)

    def _read_on_deadlines(self) -> None:
        """A block source in the daemon's process (the kernel's IIO buffer, which holds the records meanwhile): read
        every record waiting when the daemon's next output falls due, or HANDOVER_MAX_S after the last hand-over
        (`HandoverPlan`), hand the block over and make `ready_fd` readable. One read and one wake of the event loop
        per output due, instead of a read every few ms and a daemon poll on its tick (docs/daemon.md
        "Performance"). The thread waits on a timerfd that the daemon's `hand_over_by` arms for its deadline: one
        wake of this thread a read (a wake to learn of the deadline and another at it cost twice the wakes)."""
        failures = ReadFailures()
        inner, stop, clock, plan, stats, timer = self.inner, self._stop, self._clock, self._plan, self.stats, self._timer
        next_record_s = 2.0 / self.sample_rate_hz     # the longest wait for the next record after a deadline
        plan.read_at(clock())
        while not stop.is_set():
            self._arm_next_read()
            timer.wait()          # one wake a read: hand_over_by re-arms the timer for a deadline, never wakes it
            if stop.is_set():
                break
            if clock() < self._waiting_until:
                continue          # armed later meanwhile (cannot happen: only sooner), so not due yet
            self._waiting_until = math.inf
            on_due = plan.read_at(clock())
            handed = False
            try:
                with self._inner_lock:
                    samples = inner.poll()
                # no sample from the deadline on (a latest-by read came just before it, or the record is late):
                # the output goes with the next record, not with an older one or 25 ms later
                if on_due and not _reaches(samples, plan.served_s) and inner.wait(next_record_s, paced=False):
                    if len(samples):
                        self._hand_over_block(samples)    # first: kept should the next read fail (the device gone)
                        handed = True
                    with self._inner_lock:
                        samples = inner.poll()
            except Exception as exc:  # noqa: BLE001 - BusError / OSError: the source re-opens on its own
                self._read_failed(exc, failures)
                os.eventfd_write(self.ready_fd, 1)        # the daemon reports it at its next poll
                continue
            stats["reads"] += 1
            failures.read_ok()
            if len(samples) or handed:
                if len(samples):
                    self._hand_over_block(samples)
                stats["handovers"] += 1
                stats["handovers_on_due"] += on_due
                os.eventfd_write(self.ready_fd, 1)        # the daemon's loop wakes and polls (sample_reader)

    def _next_read_s(self) -> float:
        """When the block reader reads next (HandoverPlan), a deadline's read once the chip's first sample at or
        after it is in the buffer, so the output goes with a sample just made, not one up to a period old
        (docs/daemon.md "Performance")."""
        plan = self._plan
        target = plan.next_read_s()
        return self.inner.readable_after(target) if target == plan.due_s else target

    def _arm_next_read(self) -> None:
        """Arm the reader's timer for its next read. The order matters against hand_over_by (the event loop's
        thread, which arms it for a deadline sooner than `_waiting_until`): a deadline told before the second look
        is in it, one told after it sees this `_waiting_until` and arms after this arm."""
        target = self._waiting_until = self._next_read_s()
        self._timer.arm(target)
        again = self._next_read_s()
        if again < target:
            self._waiting_until = again
            self._timer.arm(again)
        if self._stop.is_set():
            self._timer.arm(0.0)       # close() armed it expired before this arm: wake to see the stop

    def _read_per_sample(self) -> None:
        """A per-sample source: the hand-over tick, wait for the next sample, read it, hand it over. The read is
        timed (`read_us_max`) and its start is the pacing's last read time. One function for the loop's work
        between two waits (and the pacing's in `wait_for_sample`): every frame less is CPU less after each
        wake's cold caches (docs/daemon.md "Performance")."""
        failures = ReadFailures()    # when a failed read is a sensor failure (drivers.read_failures)
        pacing = _Pacing(self.inner, self._clock, self._sleep_until_given, 1.0 / self.sample_rate_hz, self.stats,
                         sleep_until_default=self._sleep_until)
        stop, after_read, wait_for_sample = self._stop, self.after_read, pacing.wait_for_sample
        clock, inner_lock, read_one, stats = self._clock, self._inner_lock, self.inner.read_one, self.stats
        while not stop.is_set():
            if after_read is not None:
                after_read()
            if not wait_for_sample() or stop.is_set():
                continue
            try:
                with inner_lock:
                    woke = pacing.last_read_s = clock()
                    sample = read_one(woke)
                    read_us = (clock() - woke) * 1e6
            except Exception as exc:  # noqa: BLE001 - FrameError / BusError / SensorUnavailable / OSError
                self._read_failed(exc, failures)
                continue
            if read_us > stats["read_us_max"]:
                stats["read_us_max"] = int(read_us)
            stats["reads"] += 1
            if failures.consecutive_frame_errors:
                failures.read_ok()
            pacing.last_stale = sample is None
            if sample is not None:
                self._hand_over(sample)

    def _read_failed(self, exc: Exception, failures: ReadFailures) -> None:
        """A failed read: counted, the error set when it is a sensor failure, and a bus failure waited out (the
        inner source backs off on its own)."""
        self.stats["corrupt_frames" if isinstance(exc, FrameError) else "read_failures"] += 1
        verdict = failures.read_failed(exc)
        if verdict.failed:
            self._set_error(exc)
        if verdict.retry_after_s is not None:
            self._sleep_until(self._clock() + verdict.retry_after_s)

    def _set_error(self, exc: Exception) -> None:
        with self._lock:
            self._error = exc

    def _hand_over(self, sample: ImuSample) -> None:
        with self._lock:
            self._error = None
            if self._buffered >= self._capacity:
                self.stats["handover_dropped"] += 1
                self._gap_pending = True
                return
            if self._gap_pending:
                self._gap_pending = False
                sample = sample.with_values(flags=sample.flags | SampleFlags.GAP_BEFORE)   # an ImuSample or a SampleRecord
            self._buf.append(sample)
            self._buffered += 1
            self.stats["handed_over"] += 1
            if self._buffered > self.stats["handover_max_backlog"]:
                self.stats["handover_max_backlog"] = self._buffered

    def _hand_over_block(self, block: SampleBlock) -> None:
        """A block read at once (the kernel's buffer), kept as it is for the daemon: the rule of `_hand_over` (a
        full buffer drops what does not fit, counted, and the next sample handed over carries GAP_BEFORE), under
        one acquisition of the lock."""
        with self._lock:
            self._error = None
            n = len(block)
            room = self._capacity - self._buffered
            if room < n:
                self.stats["handover_dropped"] += n - max(0, room)
                block = _rows(block, max(0, room))
            if len(block):
                if self._gap_pending:
                    block.flags[0] |= _GAP_BEFORE     # the block's own list (drivers.iio_source decode_block)
                self._buf.append(block)
                self._buffered += len(block)
                self.stats["handed_over"] += len(block)
                if self._buffered > self.stats["handover_max_backlog"]:
                    self.stats["handover_max_backlog"] = self._buffered
            self._gap_pending = room < n

    # -- the SensorSource interface ------------------------------------------------------------------------------

    def hand_over_by(self, t: float) -> None:
        """The daemon's next output deadline (daemon.sample_reader, after every poll): a block source's reader
        hands its block over then. The reader is woken only when it waits for longer."""
        if self.ready_fd is None:
            return                   # a per-sample reader hands every sample over as it reads it
        plan = self._plan
        plan.due_s = t
        if t == plan.served_s:
            return                   # served already: the reader's next read is its latest-by one
        t = self.inner.readable_after(t)
        if t < self._waiting_until:
            self._waiting_until = t
            self._timer.arm(t)

    def poll(self) -> list[ImuSample]:
        if self._thread is None:
            self.start()
        if self.ready_fd is not None:
            try:
                os.eventfd_read(self.ready_fd)      # taken before the buffer: a block handed over after it wakes
            except BlockingIOError:                 # the daemon again
                pass
        with self._lock:
            out, self._buf, self._buffered = self._buf, [], 0
            error = self._error
        if out and type(out[0]) is SampleBlock:
            out = _joined(out)
        if not len(out) and error is not None:
            raise error
        if len(out):
            self._last_delivered = _counter(out, -1)
        return out

    def counters(self) -> dict:
        with self._inner_lock:
            c = dict(self.inner.counters())
        c.update({f"reader_{k}": v for k, v in self.stats.items()})
        return c

    def close(self) -> None:
        self._stop.set()
        if self._timer is not None:
            self._timer.arm(0.0)             # expired: the block reader wakes and sees the stop
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(2.0)
        with self._lock:     # sample indices read (or lost) after the last hand-over: the chip's truth has them
            if self._buf:
                kept = _joined(self._buf) if type(self._buf[0]) is SampleBlock else self._buf
                first = _counter(kept, 0) if self._last_delivered is None else self._last_delivered + 1
                self.stats["undelivered_at_close"] = _counter(kept, -1) - first + 1
        if self._saved_switch_interval is not None:
            sys.setswitchinterval(self._saved_switch_interval)
            self._saved_switch_interval = None
        self.inner.close()
        # a reader thread that outlived the join may still write it: its number must not go to another file
        if self.ready_fd is not None and (self._thread is None or not self._thread.is_alive()):
            os.close(self.ready_fd)
            self.ready_fd = None
            self._timer.close()


def _rows(block: SampleBlock, n: int) -> SampleBlock:
    """The first n samples of a block of columns."""
    return SampleBlock(block.t_s[:n], block.vectors[:n], block.temp_c[:n], block.supply_v[:n], block.flags[:n],
                       block.diag_stat[:n], block.counter[:n])


def _counter(samples, i: int) -> int:
    """The sample index of samples[i]: a block's column, or a sample's own."""
    return samples.counter[i] if type(samples) is SampleBlock else samples[i].counter


def _reaches(block: SampleBlock, t_s: float) -> bool:
    """Whether the block holds a sample stamped at or after `t_s`."""
    return len(block) > 0 and block.t_s[-1] >= t_s


def _joined(blocks: list[SampleBlock]) -> SampleBlock:
    """Blocks handed over since the daemon's last poll, as one (one in the common case: returned as it is)."""
    if len(blocks) == 1:
        return blocks[0]
    return SampleBlock([t for b in blocks for t in b.t_s], np.concatenate([b.vectors for b in blocks]),
                       [v for b in blocks for v in b.temp_c], [v for b in blocks for v in b.supply_v],
                       [v for b in blocks for v in b.flags], [v for b in blocks for v in b.diag_stat],
                       [v for b in blocks for v in b.counter])


class _Pacing:
    """When a per-sample reader reads next: at the chip's data-ready edge when the inner source's timer can wait
    for one (drivers.data_ready), else at its SampleTimer's next read time, with a stalled chip's re-reads spaced
    and the wakes' lateness counted (`stats`: the reader's, shared with ThreadedSource)."""

    EDGE_WAIT_S = 0.1     # a data-ready wait gives up after this, so the loop sees a stop and runs its hand-over

    def __init__(self, inner, clock, sleep_until, period_s: float, stats: dict, sleep_until_default=None):
        """sleep_until: wait until clock() ≥ t (a test's stepped clock); None: time.sleep for the time left on
        `clock` (sleep_until_default, that wait as a function, is then not called: a Python frame less a read)."""
        self.inner, self.clock, self.sleep_until, self.stats = inner, clock, sleep_until, stats
        self._sleep_until_default = sleep_until_default
        self.period_s = period_s
        self.stale_gap_s = STALE_REREAD_PERIODS * period_s
        self.last_read_s = 0.0      # when the latest read started (ThreadedSource._read_per_sample sets it)
        self.last_stale = False     # the latest read found no new sample
        self._timer = None

    def wait_for_sample(self) -> bool:
        """Wait until the next sample should be ready; False when no data-ready edge came (look again).

        The next read time is the inner source's timer's: the chip sources pass it through (ChipSource,
        ReconnectingSource and GroundTruthSource `next_read_time`), so once the timer exists it is asked
        directly, three Python frames less a read. No stale read spaced (`_spaced`) and no lateness counted
        (`_count_lateness`) in a call of their own: the loop's common case is a comparison each."""
        timer = self._timer
        if timer is None:
            # the inner source's timer exists once the chip first started, and is kept through reconnections
            # (drivers.reconnecting): looked up until then, not at every read
            timer = self._timer = self.inner.timer
            if timer is None:
                return self._wait_until(self._spaced(self.inner.next_read_time()))
        if timer.waits_for_edges:
            return timer.wait(self.EDGE_WAIT_S)
        target = timer.next_read_time()
        if self.last_stale:
            target = self._spaced(target)
        if self.sleep_until is not None or target <= 0.0:
            return self._wait_until(target)
        # `_wait_until` with time.sleep on the pacing's clock (the reader's own wait: no sleep_until given)
        clock = self.clock
        dt = target - clock()
        if dt > 0:
            time.sleep(dt)
        late_s = clock() - target
        if late_s > 0.25 * self.period_s or late_s * 1e6 > self.stats["wake_late_max_us"]:
            self._count_lateness(late_s)
        return True

    def _wait_until(self, target: float) -> bool:
        """Wait until `target` (0: read now) and count the wake's lateness."""
        if target > 0.0:
            (self.sleep_until or self._sleep_until_default)(target)
            self._count_lateness(self.clock() - target)
        return True

    def _spaced(self, target: float) -> float:
        """No new sample, and the timer's next read time is already past: the chip's data-ready stalled (the
        timer keeps its phase through a stall). Re-reading at once would busy-loop at real-time priority for the
        whole stall, starving the daemon on that core (and a unit's LimitRTTIME kills a real-time task that runs
        that long without sleeping): the next read is half a period after the last one instead."""
        if self.last_stale and target < self.last_read_s + self.stale_gap_s:
            self.stats["stale_rereads_spaced"] += 1
            return self.last_read_s + self.stale_gap_s
        return target

    def _count_lateness(self, late_s: float) -> None:
        stats = self.stats
        if late_s > 0.25 * self.period_s:     # the distribution's tail, beside bench/wake_floor.py's
            stats["wakes_late_quarter"] += 1
            if late_s > self.period_s:        # woke (and got the GIL) after the chip's next sample
                stats["wakes_late"] += 1
        if late_s * 1e6 > stats["wake_late_max_us"]:
            stats["wake_late_max_us"] = int(late_s * 1e6)
