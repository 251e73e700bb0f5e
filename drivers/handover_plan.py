"""When a sensor reader hands its samples over to the daemon: the one contract of the reader process
(drivers.process_source `_Handover`) and of the IIO reader thread (drivers.threaded_source `_read_on_deadlines`).

The daemon tells the reader when its next output falls due (`hand_over_by`, after every block it took); the
reader hands over at its first read once that deadline is reached, so the output goes out with the newest
sample and the daemon wakes once an output due, and at the latest HANDOVER_MAX_S after the last hand-over, so
samples reach the listeners, the log and the health checks without an output due. A deadline is served once:
the daemon tells the next one after it took the block (docs/daemon.md "Performance").

HANDOVER_MAX_S is below the daemon's LATE_AFTER_S (50 ms, daemon.sample_reader), so a block's oldest sample is not
counted late, and the daemon's stand-in tick waits that much longer than its own period (SampleReader `_read_batched`).
"""

from __future__ import annotations

import math

HANDOVER_MAX_S = 0.025


class HandoverPlan:
    """The reader's next hand-over: at the daemon's deadline (`due_s`) unless that one was served already, and at
    the latest `latest_s` (`max_s` after the last read; a reader draining a backlog sets it sooner)."""

    def __init__(self, max_s: float):
        self.max_s = max_s
        self.due_s = math.inf        # the daemon's next output deadline (CLOCK_MONOTONIC s; inf: none)
        self.served_s = math.inf     # the deadline the last read was made for
        self.latest_s = -math.inf    # the latest next read: `max_s` after the last one (-inf: read now)

    def next_read_s(self) -> float:
        due, latest = self.due_s, self.latest_s
        return due if due != self.served_s and due < latest else latest

    def read_at(self, now: float) -> bool:
        """A read made at `now`; True when it serves the daemon's deadline (`due_s` reached)."""
        self.latest_s = now + self.max_s
        if now >= self.due_s != self.served_s:
            self.served_s = self.due_s
            return True
        return False
