"""The clock a simulated ADIS16405 runs on (drivers.simulated): its time, how to wait on it, and the host time of
one of its times.

`ChipClock` is the host's: its waits sleep for real and its time is the host's. A test's stepped clock subclasses
it and overrides what it steps (`sleep` advancing itself, `to_host` for a chip clock that drifts from the host's).
A plain clock function (`time.monotonic`, a test's callable) is taken as a `HostClock`, so the chip asks every
clock the same members.
"""

from __future__ import annotations

import time
from collections.abc import Callable


class ChipClock:
    def __call__(self) -> float:
        raise NotImplementedError

    def sleep(self, seconds: float) -> None:
        time.sleep(seconds)

    def sleep_until(self, t: float) -> None:
        """Wait until the clock reads `t`, sleeping the host's time (a stepped clock that has no wait of its own
        is stepped by whoever drives it)."""
        dt = t - self()
        if dt > 0:
            time.sleep(dt)

    def to_host(self, t: float) -> float:
        """The host time at which this clock reads `t`."""
        return t


class HostClock(ChipClock):
    """A plain clock function on the host's waits."""

    def __init__(self, read: Callable[[], float]):
        self._read = read

    def __call__(self) -> float:
        return self._read()


def chip_clock(clock: ChipClock | Callable[[], float]) -> ChipClock:
    """`clock` as a ChipClock (a plain function on the host's waits)."""
    return clock if isinstance(clock, ChipClock) else HostClock(clock)
