"""The daemon's real per-sample reader (`Service._reader_step`: source read, error handling, pipeline, publish,
next deadline) driven on a fake clock, without an event loop or a timerfd: each step runs at the deadline the
reader armed, plus whatever lateness the test injects. What a test sees of each processed sample is what the
service's own sample listeners see."""

from __future__ import annotations

import dataclasses
import tempfile

from ahrsd.calibration.models import Calibration
from ahrsd.daemon.config import Config, StateConfig
from ahrsd.daemon.pipeline import Pipeline
from ahrsd.daemon.service import Service
from ahrsd.estimator import make_estimator


class FakeClock:
    def __init__(self, t: float = 100.0):
        self.t = t

    def __call__(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        self.t += max(0.0, s)


class _Loop:
    """What the reader asks of the event loop: the time."""

    def __init__(self, clock: FakeClock):
        self.time = clock


class _Timer:
    """What the reader asks of its DeadlineTimer: arm the next wake."""

    target = 0.0

    def arm(self, t: float) -> None:
        self.target = t


class _Done:
    """The reader's completion future: a bug in a step is re-raised by the rig."""

    exc: BaseException | None = None

    def done(self) -> bool:
        return self.exc is not None

    def set_exception(self, exc: BaseException) -> None:
        self.exc = exc


class ReaderRig(Service):
    """A Service whose reader is stepped by hand. `errors`: "frame" per rejected frame, the exception type
    name per driver error, in order; `on_sample(sample)` (optional) runs for every processed sample."""

    def __init__(self, source, clock: FakeClock, on_sample=None):
        self._state = tempfile.TemporaryDirectory()
        cfg = dataclasses.replace(Config(), endpoints=(), state=StateConfig(self._state.name))
        super().__init__(cfg, source=source)
        self.clock = clock
        self.errors: list[str] = []
        self.loop = _Loop(clock)
        self.pipeline = Pipeline(make_estimator("mekf"), Calibration.identity())
        self._reader_period = 1.0 / source.sample_rate_hz
        self._reader_timer = _Timer()
        self._reader_done = _Done()
        if on_sample is not None:
            self.add_sample_listener(lambda sample, _est: on_sample(sample))

    def _on_driver_error(self, exc: Exception) -> None:
        self.errors.append(type(exc).__name__)
        super()._on_driver_error(exc)

    def run_for(self, seconds: float, lateness=None) -> None:
        """Step the reader for `seconds` of fake time; each wake `lateness()` s after its deadline."""
        end = self.clock.t + seconds
        self._reader_timer.target = self.clock.t
        while self.clock.t < end:
            self.clock.t = max(self.clock.t, self._reader_timer.target) + (lateness() if lateness else 0.0)
            frames = self.counters.frame_errors
            self._reader_step()
            if self._reader_done.exc is not None:
                raise self._reader_done.exc
            if self.counters.frame_errors > frames:
                self.errors.append("frame")

    def close(self) -> None:
        self._state.cleanup()
