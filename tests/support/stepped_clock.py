"""A stepped clock shared by the test's main thread and a reader thread: no wall-clock time in the assertions.

The chip's sample clock and the host clock are this clock. A thread that waits on it (`sleep_until`) wakes when
the test advances it to its deadline; `run_for(d)` (called from the main thread: the event loop "busy" for d)
advances from deadline to deadline, waiting each time until every sleeper is asleep again with a later
deadline, so whatever a reader thread does between two of its deadlines happens "in no time", as on an idle
real-time core.
"""

from __future__ import annotations

import threading

from ahrsd.drivers.sim_clock import ChipClock


class ManualClock(ChipClock):
    """A clock only the test moves: it reads `t`, which the test sets, and a wait (`sleep`) advances it by the wait
    (a negative one by nothing). No `sleep_until` of its own: nothing the tests drive with it waits for a time."""

    def __init__(self, t: float = 100.0):
        self.t = t

    def __call__(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.t += max(0.0, seconds)


class SteppedClock(ChipClock):
    def __init__(self, t: float = 100.0, patience_s: float = 10.0):
        self.t = t
        self.patience_s = patience_s        # real seconds a sleeper may take to come back (a hung thread)
        self._cv = threading.Condition()
        self._sleeping: dict[int, float] = {}
        self.closed = False

    def __call__(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        """The driver's waits during start-up (self-test, reset): main thread, no reader yet."""
        self.t += max(0.0, seconds)

    def sleep_until(self, target: float) -> None:
        me = threading.get_ident()
        with self._cv:
            self._sleeping[me] = target
            self._cv.notify_all()
            while self.t < target and not self.closed:
                self._cv.wait(0.5)
            del self._sleeping[me]
            self._cv.notify_all()

    def _settled(self, sleepers: int) -> bool:
        return len(self._sleeping) >= sleepers and min(self._sleeping.values()) > self.t

    def run_for(self, seconds: float, sleepers: int = 1) -> None:
        end = self.t + seconds
        with self._cv:
            while True:
                if not self._cv.wait_for(lambda: self._settled(sleepers), timeout=self.patience_s):
                    raise AssertionError(f"no sleeper came back at t={self.t} (sleeping: {self._sleeping})")
                nxt = min(self._sleeping.values())
                if nxt > end:
                    self.t = end
                    return
                self.t = nxt
                self._cv.notify_all()

    def close(self) -> None:
        with self._cv:
            self.closed = True
            self._cv.notify_all()
