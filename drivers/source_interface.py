"""What the daemon asks of an IMU sensor source (drivers/source.py explains the two ways to read one), and the
defaults every live source shares.

Every member the daemon uses is declared here; a source implements each one (tests/test_source_interface.py
checks every source class), so no part of the daemon probes a source for what it may have.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from ahrsd.core.sample import ImuSample


class SimulatedChipView(Protocol):
    """What the daemon reads of the simulated ADIS16405 behind a source (drivers.simulated.SimulatedAdis16405,
    or a reader process's view of it): its truth counters, its sample index, the faults it injected, and its
    clock (the simulated GNSS receiver flies the same scenario on it)."""

    stats: dict
    sample_index: int
    faults: object          # .injected: {fault kind: count}

    def now(self) -> float: ...

    def helper_pids(self) -> list[int]:
        """The processes the chip's reads may wait on (its block producer): a real-time reader gives them its
        own priority (drivers.threaded_source)."""


@runtime_checkable
class SensorSource(Protocol):
    description: str
    sample_rate_hz: float
    per_sample: bool             # True: read with read_one/next_read_time (PerSampleSource); False: poll()
    monotonic_offset_s: float    # CLOCK_MONOTONIC − sample time stamps
    recording_time_base: bool    # the time stamps are a recording's (a replay): outgoing messages keep them
    finished: bool               # no sample will come any more (a replay at its end)
    chip: SimulatedChipView | None   # the simulated chip read, None for a real sensor or a recording
    ready_fd: int | None         # readable when poll() has something new (a reader process); None: poll on a tick
    handover_max_s: float        # a ready_fd source: the longest it goes without handing over (0: no promise)

    def poll(self) -> list[ImuSample]:
        """Every new sample since the last call (possibly none)."""

    def hand_over_by(self, t: float) -> None:
        """The daemon's next output deadline (CLOCK_MONOTONIC s; inf: none), told after every poll: a source
        that hands blocks over (the reader process) hands one over then; others ignore it."""

    def counters(self) -> dict: ...

    def close(self) -> None: ...


@runtime_checkable
class PerSampleSource(SensorSource, Protocol):
    """A chip read once per sample on the daemon's event loop (`per_sample` True)."""

    def read_one(self, now: float) -> ImuSample | None:
        """One read at host time `now`; the new sample or None."""

    def next_read_time(self) -> float:
        """CLOCK_MONOTONIC time of the next read (0: now)."""


@runtime_checkable
class WaitingSource(SensorSource, Protocol):
    """A block source (`per_sample` False) whose reader can wait for its data: the kernel's IIO buffer
    (drivers.iio_source), drained by a reader thread (drivers.threaded_source)."""

    def wait(self, timeout_s: float, paced: bool = True) -> bool:
        """Block until new data is ready (True) or `timeout_s` passes (False); paced: the source may hold a
        reader back so that it reads blocks, not single records (False: as soon as a record is there)."""

    def readable_after(self, t: float) -> float:
        """When the source's first sample made at or after `t` can be read (CLOCK_MONOTONIC s)."""


class LiveSource:
    """The defaults of a sensor read live: stamped in CLOCK_MONOTONIC, never finished, not a recording, no
    simulated chip behind it (a source that has one says so)."""

    monotonic_offset_s = 0.0
    recording_time_base = False
    finished = False
    chip: SimulatedChipView | None = None
    # a descriptor that becomes readable when poll() has something new (a reader process's pipe): the daemon
    # then polls when it does instead of on a fixed tick; None: poll on the tick
    ready_fd: int | None = None
    handover_max_s = 0.0

    def hand_over_by(self, t: float) -> None:
        """The daemon's next output deadline: a source that hands blocks over when asked overrides this."""
