"""The sensor reader: the per-sample timerfd loop for the chip, the polled loop for a replay, and the per-sample
hot path (pipeline, sample listeners, health bookkeeping). A failing read is counted and reported, never raised."""

from __future__ import annotations

import asyncio
import logging

from ahrsd.core.estimate import EstimateFlags
from ahrsd.core.sample import SampleFlags
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.timerfd import DeadlineTimer
from ahrsd.drivers.errors import FrameError

log = logging.getLogger(__name__)

DRIVER_RETRY_S = 0.2
LATE_AFTER_S = 0.05               # a sample used this long after it became ready is counted late (run_stats)
FRAME_ERRORS_FOR_FAILURE = 100                   # consecutive corrupt frames (≈ 0.12 s) = sensor failure

# IntFlag operators go through the enum machinery (µs each); the per-sample path tests bits on plain ints
_int_and = int.__and__
_GAP_BEFORE = int(SampleFlags.GAP_BEFORE)
_REINITIALISED = int(EstimateFlags.REINITIALISED)
_INITIALISING = int(EstimateFlags.INITIALISING)


class SampleReader:
    """Service part: the reader task (`_reader`) and the hot path (`_process`)."""

    async def _reader(self) -> None:
        if getattr(self.source, "per_sample", False):
            await self._read_per_sample()
        else:
            await self._read_batched()

    async def _read_per_sample(self) -> None:
        """Read the chip once per sample, right after it becomes ready (drivers.sample_timer).

        Deadlines are absolute CLOCK_MONOTONIC times served by a timerfd on the event loop
        (daemon.timerfd; asyncio alone sleeps in whole milliseconds); each expiry runs `_reader_step`.
        A wake later than a whole period loses a sample on the chip: it is counted (GAP_BEFORE, pipeline
        gaps, overruns) and the estimator sees the true time step.
        """
        loop = self.loop
        self._reader_period = 1.0 / self.source.sample_rate_hz
        self._reader_done = loop.create_future()
        self._reader_timer = DeadlineTimer(loop, self._reader_step)
        self._reader_timer.arm(loop.time())
        try:
            await self._reader_done
        finally:
            self._reader_timer.close()

    def _reader_step(self) -> None:
        """One wake of the per-sample reader: read, process, publish, arm the next deadline."""
        loop, source, timer = self.loop, self.source, self._reader_timer
        now = loop.time()
        self.counters.wakes += 1
        try:
            try:
                sample = source.read_one(now)
            except FrameError as exc:
                # one corrupt frame: the driver counted it; the next sample comes one period later
                self.counters.frame_errors += 1
                self._consecutive_frame_errors += 1
                if self._consecutive_frame_errors >= FRAME_ERRORS_FOR_FAILURE:
                    self._on_driver_error(exc)
                self._publish(now)      # SYS_STATUS keeps flowing (health bits) while the sensor misbehaves
                timer.arm(now + self._reader_period)
                return
            except Exception as exc:  # noqa: BLE001 - BusError or an OSError: count, report, retry
                self._on_driver_error(exc)
                self._publish(now)      # only SYS_STATUS goes out now: the GCS sees the health bits cleared
                timer.arm(now + DRIVER_RETRY_S)
                return
            self._consecutive_frame_errors = 0
            if sample is not None:
                if _int_and(sample.flags, _GAP_BEFORE):
                    self.counters.overruns += 1
                self._process((sample,), now)
            after = loop.time()
            self._publish(after)
            target = source.next_read_time()
            if target <= after:
                target = after + (0.25 * self._reader_period if sample is None else 0.0)
            timer.arm(target)
        except Exception as exc:  # noqa: BLE001 - a bug here ends the reader; run() exits non-zero
            if not self._reader_done.done():
                self._reader_done.set_exception(exc)

    async def _read_batched(self) -> None:
        """Replay: poll on a fixed absolute-deadline tick and process every sample that is due."""
        loop, source = self.loop, self.source
        period = 1.0 / self.config.sensor.poll_hz
        deadline = loop.time()
        while True:
            deadline += period
            now = loop.time()
            self.counters.wakes += 1
            try:
                samples = source.poll()
            except Exception as exc:  # noqa: BLE001
                self._on_driver_error(exc)
                self._publish(loop.time())      # SYS_STATUS keeps flowing: the GCS sees the health bits cleared
                await asyncio.sleep(DRIVER_RETRY_S)
                deadline = loop.time()
                continue
            if samples:
                self._process(samples, now)
                if self.gnss is not None:
                    self.gnss.poll()        # a GNSS recording's fixes are due by the samples' time
            elif getattr(source, "finished", False):
                log.info("replay finished")
                self.request_stop(0)
                return
            self._publish(now)
            after = loop.time()
            if after - deadline > period:
                self.counters.overruns += 1
                deadline = after
            await asyncio.sleep(max(0.0, deadline - after))

    def _process(self, samples, now: float) -> None:
        """The per-sample hot path: pipeline, listeners, health bookkeeping."""
        health, pipeline = self.health, self.pipeline
        if health.sensor_error:
            health.sensor_error = ""
            self.statustext(mavlink.MAV_SEVERITY_NOTICE, "ahrsd: sensor recovered")
        est = None
        reinitialised = False
        listeners = self._listeners
        log_put = self._sample_log_put        # daemon.vehicle_log: a queue append, never blocks
        for raw in samples:
            if log_put is not None:
                log_put(raw)
            est = pipeline.process(raw)
            if est is not None and _int_and(est.flags, _REINITIALISED):
                reinitialised = True          # on any sample of a block, not only the last one
            if listeners and est is not None:
                snapshot = pipeline.last_estimate      # listeners may keep it: the immutable one
                for fn in tuple(listeners):
                    try:
                        fn(pipeline.last_sample, snapshot)
                    except Exception:  # noqa: BLE001 - a faulty listener is dropped, the reader carries on
                        log.exception("sample listener %r failed; removed", fn)
                        listeners.remove(fn)
        if not self.recording_time_base:           # samples are in time order: count from the oldest
            ready_by = now - LATE_AFTER_S - getattr(self.source, "monotonic_offset_s", 0.0)
            for raw in samples:
                if raw.t_s >= ready_by:
                    break
                self.counters.late_samples += 1
        health.last_sample_time = now
        health.last_sample_flags = samples[-1].flags
        if reinitialised:
            self.signal_heading_reset()           # a genuine re-initialisation: signalled, not slewed
        if est is not None:
            health.last_estimate_flags = est.flags
            if not self.ready_sent and not _int_and(est.flags, _INITIALISING):
                self.ready_sent = True
                self.notifier.ready("running")
                log.info("first good estimate: READY")

    def sample_time_monotonic(self, t_s: float) -> float:
        """The time a message carries for a sample stamped t_s: CLOCK_MONOTONIC (the chip source stamps in
        that clock already); a replay keeps the recording's t_s (Service.recording_time_base)."""
        if self.recording_time_base:
            return t_s
        return t_s + getattr(self.source, "monotonic_offset_s", 0.0)

    def _on_driver_error(self, exc: Exception) -> None:
        self.counters.driver_errors += 1
        first = not self.health.sensor_error
        self.health.sensor_error = str(exc) or type(exc).__name__
        if first:
            log.error("sensor read failed: %s", exc)
            self.statustext(mavlink.MAV_SEVERITY_CRITICAL, f"ahrsd: sensor failure: {self.health.sensor_error}")

