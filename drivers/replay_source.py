"""A recording as a sensor source: samples released when their time comes (realtime) or all at once (fast)."""

from __future__ import annotations

import time
from dataclasses import replace
from collections.abc import Generator
from typing import Iterator

from ahrsd.core.sample import ImuSample, SampleFlags
from ahrsd.drivers.chip_source import ADIS16405_RATE_HZ

MAX_SAMPLES_PER_POLL = 64          # bound one poll's work (a stall is reported as a gap, not a burst)
_GAP_BEFORE = int(SampleFlags.GAP_BEFORE)


class ReplaySource:
    """Samples from a recording, released when their time comes (realtime) or all at once (fast).

    A jump in the recorded sample counter is a gap: the sample after it carries GAP_BEFORE (the one place
    gaps are detected, like the chip source's timer for live data).
    """

    per_sample = False   # polled on a fixed tick; each poll returns every sample that is due
    monotonic_offset_s = 0.0   # CLOCK_MONOTONIC − recording time (set at the first sample; at speed 1)
    recording_time_base = True   # outgoing messages carry the recording's t_s (what a plot lines up with)
    chip = None                  # a recording: no simulated chip behind it
    ready_fd = None              # polled on the tick
    handover_max_s = 0.0

    def hand_over_by(self, t: float) -> None:
        """A recording is released by its own clock: the daemon's output deadlines change nothing."""
    description: str
    sample_rate_hz: float
    finished: bool

    def __init__(self, samples: Iterator[ImuSample], description: str, realtime: bool = True,
                 rate_hz: float = ADIS16405_RATE_HZ, clock=time.monotonic, speed: float = 1.0):
        if not speed > 0:
            raise ValueError(f"replay speed must be > 0, not {speed!r}")
        self._it = iter(samples)
        self.description = description
        self.realtime = realtime
        self.speed = float(speed)        # realtime: recording seconds per second of `clock`
        self.sample_rate_hz = rate_hz
        self._clock = clock
        self._pending: ImuSample | None = None
        self._t0_clock: float | None = None
        self._t0_sample = 0.0
        self._last_counter: int | None = None
        self.finished = False
        self.error: Exception | None = None   # what ended the replay early (an unreadable row): the run failed

    def poll(self) -> list[ImuSample]:
        out: list[ImuSample] = []
        now = self._clock()
        while len(out) < MAX_SAMPLES_PER_POLL:
            if self._pending is None:
                try:
                    self._pending = next(self._it)
                except StopIteration:
                    self.finished = True
                    break
                except Exception as exc:
                    self.error, self.finished = exc, True
                    raise
                if self._t0_clock is None:
                    self._t0_clock, self._t0_sample = now, self._pending.t_s
                    self.monotonic_offset_s = now - self._pending.t_s
            if self.realtime and self._pending.t_s - self._t0_sample > (now - self._t0_clock) * self.speed:
                break
            s, self._pending = self._pending, None
            last, self._last_counter = self._last_counter, s.counter
            if last is not None and s.counter > last + 1 and not int(s.flags) & _GAP_BEFORE:
                s = replace(s, flags=s.flags | SampleFlags.GAP_BEFORE)
            out.append(s)
        return out

    def counters(self) -> dict:
        return {}

    def close(self) -> None:
        if isinstance(self._it, Generator):      # a recording read lazily (iter_samples): its file closes with it
            self._it.close()
