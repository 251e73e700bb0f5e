"""The daemon's real per-sample reader (`SampleReader.step`: source read, error handling, pipeline, publish,
next deadline) built alone and driven on a fake clock, without an event loop or a timerfd: each step runs at
the deadline the reader armed, plus whatever lateness the test injects. What a test sees of each processed
sample is what the daemon's sample listeners see."""

from __future__ import annotations

from ahrsd.calibration.models import Calibration
from ahrsd.daemon.counters import ServiceCounters
from ahrsd.daemon.health import Health
from ahrsd.daemon.pipeline import Pipeline
from ahrsd.daemon.sample_reader import ReaderOutputs, SampleListeners, SampleReader
from ahrsd.estimator import make_estimator
from support.stepped_clock import ManualClock


class _Loop:
    """What the reader asks of the event loop: the time."""

    def __init__(self, clock: ManualClock):
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


class ReaderRig(SampleReader):
    """The daemon's SampleReader stepped by hand. `errors`: "frame" per rejected frame, the exception type
    name per driver error, in order; `on_sample(sample)` (optional) runs for every processed sample;
    `texts`: the STATUSTEXTs it sent."""

    def __init__(self, source, clock: ManualClock, on_sample=None):
        listeners = SampleListeners()
        self.texts: list[tuple[int, str]] = []
        self.published = 0
        super().__init__(source, Pipeline(make_estimator("mekf"), Calibration.identity()),
                         Health(stale_timeout_s=0.1), ServiceCounters(), listeners,
                         ReaderOutputs(publish=self._publish, statustext=lambda sev, text: self.texts.append((sev, text)),
                                       heading_reset=lambda: None, ready=lambda: None),
                         poll_hz=100.0)
        self.clock = clock
        self.period_s = 1.0 / source.sample_rate_hz
        self.errors: list[str] = []
        self.loop = _Loop(clock)
        self.timer = _Timer()
        self.done = _Done()
        if on_sample is not None:
            listeners.add(lambda sample, _est: on_sample(sample))

    def _publish(self, now: float) -> None:
        self.published += 1

    def on_driver_error(self, exc: Exception) -> None:
        self.errors.append(type(exc).__name__)
        super().on_driver_error(exc)

    def run_for(self, seconds: float, lateness=None) -> None:
        """Step the reader for `seconds` of fake time; each wake `lateness()` s after its deadline."""
        end = self.clock.t + seconds
        self.timer.target = self.clock.t
        while self.clock.t < end:
            self.clock.t = max(self.clock.t, self.timer.target) + (lateness() if lateness else 0.0)
            frames = self.counters.frame_errors
            self.step()
            if self.done.exc is not None:
                raise self.done.exc
            if self.counters.frame_errors > frames:
                self.errors.append("frame")

    def close(self) -> None:
        pass
