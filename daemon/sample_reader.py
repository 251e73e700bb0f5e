"""The sensor reader: the per-sample timerfd loop for the chip, the polled loop for a replay, and the per-sample
hot path (pipeline, sample listeners, health bookkeeping). A failing read is counted and reported, never raised.

Input: a sensor source (drivers.source: `read_one`/`next_read_time` per sample, or `poll` for a replay) and the
pipeline; output: the callbacks of `ReaderOutputs`. The reader knows nothing else of the daemon."""

from __future__ import annotations

import asyncio
import logging
import math
from dataclasses import dataclass
from typing import Callable, Sequence

from ahrsd.core.estimate import EstimateFlags
from ahrsd.core.sample import ImuSample, SampleFlags
from ahrsd.core.sample_block import SampleBlock
from ahrsd.daemon.counters import ServiceCounters
from ahrsd.daemon.health import Health
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.pipeline import Pipeline, or_all
from ahrsd.daemon.timerfd import DeadlineTimer
from ahrsd.drivers.errors import FrameError
from ahrsd.drivers.read_failures import FRAME_ERRORS_FOR_FAILURE
from ahrsd.drivers.read_failures import RETRY_AFTER_FAILURE_S as DRIVER_RETRY_S
from ahrsd.drivers.source_interface import SensorSource

log = logging.getLogger(__name__)

LATE_AFTER_S = 0.05               # a sample used this long after it became ready is counted late (run_stats)

# IntFlag operators go through the enum machinery (a Python call each); the per-sample path tests bits on plain ints
_int_and = int.__and__
_GAP_BEFORE = int(SampleFlags.GAP_BEFORE)
_REINITIALISED = int(EstimateFlags.REINITIALISED)
_INITIALISING = int(EstimateFlags.INITIALISING)


class SampleListeners:
    """`fn(calibrated_sample, estimate)` after every sample (keep it cheap); a listener that raises is dropped.

    `estimate` is the immutable AttitudeEstimate of the sample (the listener may keep it), built for the sample
    because a listener asked for it. A listener added with `in_place=True` gets the estimator's latest estimate
    read in place instead (the pipeline's step result: valid until the next sample, `snapshot()` where the
    estimator has a view) and costs no estimate: at 819.2 SPS building one for every sample would cost more than
    the filter step (estimator/estimate_view.py).

    A listener added with `steps_ahead=` (a predicate) says that while it returns true the listener reads no more
    of a sample's estimate than its flags and time and swaps no calibration or mounting at a sample: the estimator
    may then step a run of the block's samples in one call before their listeners run (daemon.pipeline
    `process_block(stepped_ahead=True)`; ins: one compiled call for ~12 samples). Every listener must say so for
    that; one without a predicate keeps the block stepped sample by sample.

    A listener added with `runs=(on_run, when)` as well takes a whole run of stepped-ahead samples in one call
    while `when()` (and its `steps_ahead`) is true: `on_run(t_s, rows, estimate)` once after the run, with the
    samples' times and calibrated body-frame (n, 9) rows (gyro, accel, mag: a view; copy what outlives the block)
    and the estimate left at the run's last sample, instead of `fn` at each of its samples. When every listener
    takes runs, the pipeline does the run's per-sample bookkeeping at once (`process_block(whole_runs=True)`): no
    per-sample Python at all for the run's samples (a listener does for the run what `fn` would have done for each
    of its samples, in order; listeners are called one after the other for the run, not sample by sample)."""

    def __init__(self):
        self.fns: list[Callable] = []
        self.in_place: set[Callable] = set()
        self.steps_ahead: dict[Callable, Callable[[], bool]] = {}
        self.runs: dict[Callable, tuple[Callable, Callable[[], bool]]] = {}

    def add(self, fn: Callable, *, in_place: bool = False, steps_ahead: Callable[[], bool] | None = None,
            runs: tuple[Callable, Callable[[], bool]] | None = None) -> Callable[[], None]:
        """Add `fn`; returns the remover."""
        self.fns.append(fn)
        if in_place:
            self.in_place.add(fn)
        if steps_ahead is not None:
            self.steps_ahead[fn] = steps_ahead
        if runs is not None:
            self.runs[fn] = runs

        def remove() -> None:
            self.drop(fn)
        return remove

    def drop(self, fn: Callable) -> None:
        if fn in self.fns:
            self.fns.remove(fn)
        self.in_place.discard(fn)
        if fn not in self.fns:
            self.steps_ahead.pop(fn, None)
            self.runs.pop(fn, None)

    def allow_steps_ahead(self) -> bool:
        """Whether every listener lets the estimator step a run of samples before their listeners (the class's
        doc): once a block."""
        ahead = self.steps_ahead
        for fn in self.fns:
            allowed = ahead.get(fn)
            if allowed is None or not allowed():
                return False
        return True

    def take_runs(self) -> bool:
        """Whether every listener takes whole runs now (the class's doc; steps ahead allowed as well): once a
        block."""
        runs = self.runs
        for fn in self.fns:
            run = runs.get(fn)
            if run is None or not run[1]():
                return False
        return self.allow_steps_ahead()


@dataclass
class ReaderOutputs:
    """What the reader calls. `publish(now)` after every wake; `statustext(severity, text)`;
    `heading_reset()` on an estimator re-initialisation; `ready()` on the first good estimate; `batch_done(t_s)`
    after each replay batch (a GNSS replay in step); `finished()` when a replay has no more samples;
    `raw_sink(sample)` every raw sample (the vehicle log; None = not logging); `next_due()` when an output falls
    due next (CLOCK_MONOTONIC s, inf: none), told to a source that hands blocks over when asked (`hand_over_by`)."""

    publish: Callable[[float], None]
    statustext: Callable[[int, str], None]
    heading_reset: Callable[[], None]
    ready: Callable[[], None]
    batch_done: Callable[[float], None] = lambda t_s: None
    finished: Callable[[], None] = lambda: None
    raw_sink: Callable | None = None
    next_due: Callable[[], float] = lambda: math.inf


class SampleReader:
    """The reader task (`run`, on the event loop) and the hot path (`process`). source None: no reader task;
    the caller feeds `process` itself (a test, through Service.use_pipeline without a source)."""

    def __init__(self, source: SensorSource | None, pipeline: Pipeline, health: Health, counters: ServiceCounters,
                 listeners: SampleListeners, outputs: ReaderOutputs, *, poll_hz: float):
        self.source = source
        self.pipeline = pipeline
        self.health = health
        self.counters = counters
        self.listeners = listeners
        self.outputs = outputs
        self.poll_hz = poll_hz
        self.ready_sent = False
        self.loop = None
        self.period_s = 0.0               # one sample period of the source (set when the reader runs)
        self.timer = None
        self.done: asyncio.Future | None = None
        self._consecutive_frame_errors = 0
        self._after_output: list[Callable[[], None]] = []     # after_output's work, for the end of the next wake

    def after_output(self, fn: Callable[[], None]) -> None:
        """Run `fn()` once at the end of the reader's next wake, after the outputs of the samples it took were sent:
        work that no output waits for (a GNSS fix's delivery: its cost on the loop in docs/daemon.md "Performance")
        then runs behind the outputs due, not in front of them. A `fn` that raises is logged; the reader goes on.
        While the reader does not run (not started, stopped, no source) no wake will come: `fn` runs now."""
        if self.done is None or self.done.done():
            fn()
            return
        self._after_output.append(fn)

    def _run_after_output(self) -> None:
        work, self._after_output = self._after_output, []
        for fn in work:
            try:
                fn()
            except Exception:  # noqa: BLE001 - deferred work must not end the reader
                log.exception("work after the outputs (%r) failed", fn)

    async def run(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop = loop
        if self.source.per_sample:
            await self._read_per_sample()
        else:
            await self._read_batched()

    async def _read_per_sample(self) -> None:
        """Read the chip once per sample, right after it becomes ready (drivers.sample_timer).

        Deadlines are absolute CLOCK_MONOTONIC times served by a timerfd on the event loop
        (daemon.timerfd; asyncio alone sleeps in whole milliseconds); each expiry runs `step`.
        A wake later than a whole period loses a sample on the chip: it is counted (GAP_BEFORE, pipeline
        gaps, overruns) and the estimator sees the true time step.
        """
        loop = self.loop
        self.period_s = 1.0 / self.source.sample_rate_hz
        self.done = loop.create_future()
        self.timer = DeadlineTimer(loop, self.step)
        self.timer.arm(loop.time())
        try:
            await self.done
        finally:
            self.timer.close()

    def step(self) -> None:
        """One wake of the per-sample reader: read, process, publish, arm the next deadline."""
        loop, source, timer, out = self.loop, self.source, self.timer, self.outputs
        now = loop.time()
        self.counters.wakes += 1
        try:
            try:
                sample = source.read_one(now)
            except FrameError as exc:
                # one corrupt frame: the driver counted it; the next sample comes one period later
                self.health.empty_read(now)
                self.counters.frame_errors += 1
                self._consecutive_frame_errors += 1
                if self._consecutive_frame_errors >= FRAME_ERRORS_FOR_FAILURE:
                    self.on_driver_error(exc)
                out.publish(now)      # SYS_STATUS keeps flowing (health bits) while the sensor misbehaves
                timer.arm(now + self.period_s)
                return
            except Exception as exc:  # noqa: BLE001 - BusError or an OSError: count, report, retry
                self.on_driver_error(exc)
                out.publish(now)      # only SYS_STATUS goes out now: the GCS sees the health bits cleared
                timer.arm(now + DRIVER_RETRY_S)
                return
            self._consecutive_frame_errors = 0
            if sample is not None:
                if _int_and(sample.flags, _GAP_BEFORE):
                    self.counters.overruns += 1
                self.process((sample,), now)
            else:
                self.health.empty_read(now)
            after = loop.time()
            out.publish(after)
            target = source.next_read_time()
            if target <= after:
                target = after + (0.25 * self.period_s if sample is None else 0.0)
            timer.arm(target)
            if self._after_output:
                self._run_after_output()        # after the outputs, as in _batch_step
        except Exception as exc:  # noqa: BLE001 - a bug here ends the reader; run() exits non-zero
            if not self.done.done():
                self.done.set_exception(exc)

    async def _read_batched(self) -> None:
        """Replay and block sources (a reader thread or process, drivers.threaded_source / process_source): poll
        on a fixed absolute-deadline tick and process every sample that is due.

        Each tick is a loop callback at its deadline (`loop.call_at`, the clock and rounding of `asyncio.sleep`),
        not a task resumed by a sleep: no future, no extra loop iteration to resume the task, 200 times a second.

        A source with a `ready_fd` (the reader process's pipe) is polled when that descriptor becomes readable,
        i.e. when the reader hands a block over, and the tick only stands in when nothing came for two to four tick
        periods (a stalled or failed sensor: SYS_STATUS and the health checks go on). The reader then hands over
        once a tick period instead of twice as often to meet the tick, and the newest sample of a block reaches
        the outputs as soon as it is handed over rather than at the next tick.

        A source that hands over when asked (`hand_over_by`: the reader process) is told after every wake when
        the next output falls due (`ReaderOutputs.next_due`), and hands its block over then, or at the latest
        `handover_max_s` after the last one: a wake per output due instead of one per fixed hand-over period, and
        the output still goes out with the newest sample. The stand-in tick then waits `handover_max_s` longer.
        """
        loop = self.loop
        self._tick_period_s = 1.0 / self.poll_hz
        self._standin_s = self.source.handover_max_s
        self._deadline = loop.time()
        self._tick_handle: asyncio.TimerHandle | None = None
        self.done = loop.create_future()
        fd = self.source.ready_fd
        self._on_data = fd is not None
        if fd is not None:
            loop.add_reader(fd, self._data_step)
        self._batch_step()
        try:
            await self.done
        finally:
            if fd is not None:
                loop.remove_reader(fd)        # (a no-op when a failed poll already did)
            if self._tick_handle is not None:
                self._tick_handle.cancel()

    def _data_step(self) -> None:
        """The source's descriptor is readable: a look now; the stand-in tick is kept two to four periods ahead
        (moved only when it came within two: a timer re-armed at every block costs more than the look's poll)."""
        self._batch_step(on_data=True)

    def _batch_step(self, on_data: bool = False) -> None:
        """One tick of the polled reader (or a look when the source's descriptor became readable): poll,
        process, publish, schedule the next tick."""
        loop, source, out, done = self.loop, self.source, self.outputs, self.done
        if done.done():           # a look queued before the reader stopped: its source may be closed already
            return
        period = self._tick_period_s
        try:
            if not on_data:
                self._deadline += period
            now = loop.time()
            self.counters.wakes += 1
            try:
                samples = source.poll()
            except Exception as exc:  # noqa: BLE001 - a bus failure (a threaded chip source reports it here)
                self.on_driver_error(exc)
                out.publish(now)      # only SYS_STATUS goes out now: the GCS sees the health bits cleared
                if self._on_data:     # a reader process that ended stays readable: wait out the retry
                    loop.remove_reader(source.ready_fd)
                self._tick_handle = loop.call_later(DRIVER_RETRY_S, self._batch_retry)
                return
            if samples:
                out.batch_done(self.process(samples, now))
            elif source.finished:
                log.info("replay finished")
                out.finished()
                if not done.done():
                    done.set_result(None)
                return
            else:
                self.health.empty_read(now)
            out.publish(now)
            source.hand_over_by(out.next_due())
            if self._after_output:
                self._run_after_output()        # the outputs above were sent: now the work that waited for them
            after = loop.time()
            if on_data:
                handle = self._tick_handle
                standin = self._standin_s
                if handle is not None and not handle.cancelled() and handle.when() - after >= standin + 2 * period:
                    return
                if handle is not None:
                    handle.cancel()           # a cancelled timer at the heap's head never wakes the loop
                # the stand-in tick's own deadline is one period on; kept ahead by one more hand-over at least
                self._deadline = after + 2 * standin + 3 * period
                self._tick_handle = loop.call_at(after + 2 * standin + 4 * period, self._batch_step)
                return
            if after - self._deadline > period:
                self.counters.overruns += 1
                self._deadline = after
            self._tick_handle = loop.call_at(max(after, self._deadline), self._batch_step)
        except Exception as exc:  # noqa: BLE001 - a bug here ends the reader; run() exits non-zero
            if not done.done():
                done.set_exception(exc)

    def _batch_retry(self) -> None:
        """After a failed poll and DRIVER_RETRY_S: the tick restarts from now."""
        if self.done.done():      # stopped meanwhile (its source closed): nothing to re-register
            return
        self._deadline = self.loop.time()
        if self._on_data:
            self.loop.add_reader(self.source.ready_fd, self._data_step)
        self._batch_step()

    def process(self, block: SampleBlock | Sequence[ImuSample], now: float) -> float:
        """The per-sample hot path: pipeline, listeners, health bookkeeping, for a block of samples (a reader
        process's) or a sequence of ImuSamples (made a block: `SampleBlock.of`). Returns the last sample's time."""
        if type(block) is not SampleBlock:
            block = SampleBlock.of(block)
        health, out = self.health, self.outputs
        if health.sensor_error:
            health.sensor_error = ""
            out.statustext(mavlink.MAV_SEVERITY_NOTICE, "ahrsd: sensor recovered")
        log_put = out.raw_sink                # daemon.vehicle_log: a queue append, never blocks
        if log_put is not None:
            for raw in block:
                log_put(raw)
        est, reinitialised = self._estimate(block)
        source = self.source
        if source is None or not source.recording_time_base:   # samples in time order: count from the oldest
            self._count_late(block, now - LATE_AFTER_S - (source.monotonic_offset_s if source is not None else 0.0))
        self._bookkeep(block, est, reinitialised, now)
        return block.t_s[-1]

    def _estimate(self, block: SampleBlock):
        """The pipeline over the block, each estimate handed to the listeners. Returns the last estimate (None
        when the block gave none) and whether any sample of the block re-initialised the estimator."""
        pipeline = self.pipeline
        est = None
        reinitialised = False
        listeners = self.listeners.fns
        in_place = self.listeners.in_place
        whole_runs = self.listeners.take_runs()
        # the block stays columns: calibrated at once, only the calibrated samples built
        for est in pipeline.process_block(block, whole_runs or self.listeners.allow_steps_ahead(), whole_runs):
            if whole_runs and pipeline.run is not None:          # a run's samples at once (SampleListeners)
                first, stop, run_bits = pipeline.run
                if or_all(run_bits) & _REINITIALISED:
                    reinitialised = True
                if listeners:
                    self._run_listeners(block.t_s[first:stop], pipeline.run_rows, est)
                continue
            if est is not None and _int_and(est.flags, _REINITIALISED):
                reinitialised = True          # on any sample of a block, not only the last one
            if listeners and est is not None:
                snapshot = None                        # built only for a listener that keeps it
                for fn in tuple(listeners):
                    if fn in in_place:
                        given = est
                    else:
                        if snapshot is None:
                            snapshot = pipeline.last_estimate
                        given = snapshot
                    try:
                        fn(pipeline.last_sample, given)
                    except Exception:  # noqa: BLE001 - a faulty listener is dropped, the reader carries on
                        log.exception("sample listener %r failed; removed", fn)
                        self.listeners.drop(fn)
        return est, reinitialised

    def _run_listeners(self, t_s, rows, est) -> None:
        """Every listener's run form for a run of samples (SampleListeners); one that raises is dropped."""
        runs = self.listeners.runs
        for fn in tuple(self.listeners.fns):
            try:
                runs[fn][0](t_s, rows, est)
            except Exception:  # noqa: BLE001 - a faulty listener is dropped, the reader carries on
                log.exception("sample listener %r failed; removed", fn)
                self.listeners.drop(fn)

    def _count_late(self, block: SampleBlock, ready_by: float) -> None:
        """Count the block's samples that became ready before `ready_by` (used LATE_AFTER_S or more after)."""
        for t_s in block.t_s:
            if t_s >= ready_by:
                break
            self.counters.late_samples += 1

    def _bookkeep(self, block: SampleBlock, est, reinitialised: bool, now: float) -> None:
        """The health's view of the block just processed; a re-initialisation signalled, READY on the first good
        estimate."""
        health, out = self.health, self.outputs
        health.sample_read(now)
        health.last_sample_flags = block.flags[-1]
        if reinitialised:
            out.heading_reset()           # a genuine re-initialisation: signalled, not slewed
        if est is not None:
            health.last_estimate_flags = est.flags
            if not self.ready_sent and not _int_and(est.flags, _INITIALISING):
                self.ready_sent = True
                out.ready()
                log.info("first good estimate: READY")

    def on_driver_error(self, exc: Exception) -> None:
        self.counters.driver_errors += 1
        first = not self.health.sensor_error
        self.health.sensor_error = str(exc) or type(exc).__name__
        if first:
            log.error("sensor read failed: %s", exc)
            self.outputs.statustext(mavlink.MAV_SEVERITY_CRITICAL, f"ahrsd: sensor failure: {self.health.sensor_error}")
