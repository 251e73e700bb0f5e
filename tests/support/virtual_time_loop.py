"""An asyncio event loop on a virtual clock: the real loop (its timers, `call_at`, `add_reader`, tasks, futures),
but `time()` is a number that jumps to the next timer's deadline whenever the loop would wait for it. Seconds of
loop time run in milliseconds, and every assertion counts events on that clock: nothing depends on how fast the
machine is.

Everything that happens must be a loop event (a timer, or a descriptor made readable by a timer's callback), so
no wait is ever cut short by an outside event. `iterations` counts the loop's iterations (its wakes)."""

from __future__ import annotations

import asyncio


class VirtualTimeLoop(asyncio.SelectorEventLoop):
    def __init__(self, start_s: float = 1000.0):
        super().__init__()
        self.now_s = start_s
        self.iterations = 0
        select = self._selector.select

        def select_in_virtual_time(timeout=None):
            # the loop waits `timeout` for a timer (None: for ever — nothing left to happen, a test's bug)
            if timeout is None:
                raise RuntimeError("the virtual-time loop has nothing scheduled: it would wait for ever")
            self.now_s += max(0.0, timeout)
            return select(0)

        self._selector.select = select_in_virtual_time

    def time(self) -> float:
        return self.now_s

    def _run_once(self) -> None:
        self.iterations += 1
        super()._run_once()
