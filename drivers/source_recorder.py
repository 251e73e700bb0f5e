"""Reading a per-sample sensor source into a recording, a sample at a time: the loop of `ahrsd record`.

It reads the way the daemon reads a chip on its event loop: once per sample, when the source's sample timer
expects the next one (`next_read_time`), and it judges failed reads by the daemon's policy
(drivers.read_failures): a corrupt frame is skipped and the next sample read a period later, until
FRAME_ERRORS_FOR_FAILURE come in a row; any other read error fails the sensor at once. Where the daemon
reports a failed sensor and keeps retrying, a recording stops there: a recording with a hole the size of an
outage is not what was asked for.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from ahrsd.core.sample import ImuSample
from ahrsd.drivers.errors import DriverError, FrameError
from ahrsd.drivers.read_failures import ReadFailures
from ahrsd.drivers.recording import RecordingWriter
from ahrsd.drivers.chip_source import ChipSource

# A source with no sample ready yet is read again after this share of a period (there is no data-ready line).
EMPTY_READ_RETRY_PERIODS = 0.25


class SourceRecorder:
    """Writes every sample the chip `source` delivers to `writer` until `run` has written its count, the sensor fails,
    or the caller interrupts it (KeyboardInterrupt propagates; what was written so far is on the object).

    paced: read on the host clock when the sample timer expects a sample (a real chip, or a simulated one on
    the wall clock); unpaced: read as fast as the source answers (a free-running simulated chip).
    truth_q_wxyz: the simulated chip's truth for the sample just read (the recording's truth columns), or None.
    on_sample(sample): called after each sample is written (a GNSS recorder's poll, a status line).
    """

    def __init__(self, source: ChipSource, writer: RecordingWriter, *, paced: bool,
                 truth_q_wxyz: Callable[[], np.ndarray | None] | None = None,
                 on_sample: Callable[[ImuSample], None] | None = None,
                 clock: Callable[[], float] = time.monotonic, sleep: Callable[[float], None] = time.sleep):
        self.source = source
        self.writer = writer
        self.paced = paced
        self._truth_q_wxyz = truth_q_wxyz
        self._on_sample = on_sample
        self._clock, self._sleep = clock, sleep
        self.failures = ReadFailures()     # the daemon's failure policy
        self.written = 0
        self.first: ImuSample | None = None
        self.last: ImuSample | None = None
        self.failure: str | None = None    # why the sensor counts as failed, once it does

    @property
    def span_s(self) -> float:
        """Sample time from the first sample written to the last (0 before two)."""
        return 0.0 if self.first is None else self.last.t_s - self.first.t_s

    def run(self, n_samples: int | None) -> bool:
        """Read and write until `n_samples` are written (None: until interrupted) or the sensor fails.
        Returns False when it stopped on a failed sensor (`failure` says why)."""
        period = self.source.driver.sample_period_s
        next_poll = self._clock()
        while n_samples is None or self.written < n_samples:
            if self.paced:
                delay = next_poll - self._clock()
                if delay > 0:
                    self._sleep(delay)
            try:
                sample = self.source.read_one(self.source.clock())
            except (DriverError, OSError) as exc:
                if self.failures.read_failed(exc).failed:
                    why = (f" ({self.failures.consecutive_frame_errors} corrupt frames in a row)"
                           if isinstance(exc, FrameError) else "")
                    self.failure = f"sensor failure{why}: {exc}"
                    return False
                next_poll = self._clock() + period   # a corrupt frame: read the next sample
                continue
            self.failures.read_ok()
            if self.paced:
                # no data-ready line: read when the sample timer expects the next sample
                next_poll = max(self.source.next_read_time(),
                                self._clock() + (EMPTY_READ_RETRY_PERIODS * period if sample is None else 0.0))
            if sample is not None:
                self._write(sample)
        return True

    def _write(self, sample: ImuSample) -> None:
        truth = self._truth_q_wxyz() if self._truth_q_wxyz is not None else None
        self.writer.write(sample, truth_q_wxyz=truth)
        self.written += 1
        self.first = sample if self.first is None else self.first
        self.last = sample
        if self._on_sample is not None:
            self._on_sample(sample)
