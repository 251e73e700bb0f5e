"""Fix time stamps from the receiver's own epoch time, so a late read does not make a late (or backwards) stamp.

A serial fix's arrival stamp (host clock when its last byte was read − the receiver's output latency) is late
by however long the reader was held up. The receiver's epoch time (UBX iTOW, NMEA UTC time of day) is not:
it says when the measurement was made, on the receiver's clock. The offset host − receiver, observed as
(arrival stamp − receiver time), is the true offset plus that fix's delay, and a delay is never negative, so
the smallest offset seen over a window is the best estimate; each fix is stamped at its receiver time plus
that minimum. This is ArduPilot's jitter correction (libraries/AP_RTC/JitterCorrection.cpp,
`correct_offboard_timestamp_usec`: "the data did not come from the future", converge on the offset of the
least-lagged message), with a sliding window in receiver time instead of its blocks of 100 messages, so a
host clock drifting against the receiver's is followed within one window.

Properties (with the receiver's time increasing): a stamp is never later than its own arrival stamp (the
window holds the fix's own offset); consecutive stamps never go backwards unless the minimum itself falls
by more than the epochs' spacing (a newly seen, less-delayed fix showing that earlier stamps were late: at
start-up, or after a load spike longer than the window); the stamp is then held at the previous one + 1 ms
and counted (`stamps_held`): every consumer (the edge validator, the ins) refuses a time that is not after
the previous one, and the held stamp is no later than the fix's arrival stamp (+ 1 ms a held fix), so the
fix is kept with no worse a time than stamping by arrival would give it.

All fixes of one read are entered into the window before any is stamped: the last of a burst that a held-up
reader found waiting is the least delayed, and stamps the earlier ones back from it.

The receiver's clock: its time wraps (the GPS week for iTOW, the UTC day for NMEA), which is unwrapped; it
may jump (a receiver reset, a time fix after a cold start). Jumping back (the unwrapped time going backwards),
or an offset more than MAX_LAG_S away from the window's minimum (more than a serial buffer's backlog, and
not a delay a read could have), re-seeds the window at that fix's own arrival stamp; counted
(`receiver_clock_jumps`). A fix without a receiver time keeps its arrival stamp.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections import deque

from ahrsd.core.gnss import GnssFix

log = logging.getLogger(__name__)

WINDOW_S = 20.0          # receiver seconds over which the minimum offset is taken
MAX_LAG_S = 10.0         # an offset further than this from the minimum is a receiver clock jump, not a delay
HOLD_STEP_S = 1e-3       # a stamp that would go backwards is put this far after the previous one (iTOW's unit)
RECEIVER_TIME_KEY = "receiver_time_s"


class ReceiverTimeStamper:
    """Stamps one receiver's fixes at receiver time + the minimum (arrival stamp − receiver time) of the
    last WINDOW_S receiver seconds. `period_s`: where the receiver time wraps (604800 s for iTOW, 86400 s for
    an NMEA time of day). Call `stamp_read(fixes)` with the fixes of one read, oldest first."""

    def __init__(self, period_s: float, name: str = "gnss"):
        self.period_s = float(period_s)
        self.name = name
        self.receiver_clock_jumps = 0
        self.stamps_held = 0
        self.wraps = 0
        self._window: deque[tuple[float, float]] = deque()   # (unwrapped receiver time, offset); offsets rise
        self._last_rx_s = math.nan          # unwrapped receiver time of the last timed fix
        self._last_stamp_s = -math.inf

    @property
    def offset_s(self) -> float:
        """The current estimate of host − receiver time (NaN before the first timed fix)."""
        return self._window[0][1] if self._window else math.nan

    def stamp_read(self, fixes: list[GnssFix]) -> list[GnssFix]:
        """The fixes of one read, each with its `t_s` from its receiver time (its arrival stamp without one)."""
        out: list[GnssFix] = []
        segment: list[tuple[GnssFix, float]] = []       # timed fixes entered into the window, not yet stamped
        for fix in fixes:
            rx = fix.extra.get(RECEIVER_TIME_KEY, math.nan)
            if not math.isfinite(rx) or not math.isfinite(fix.t_s):
                out += self._stamp_segment(segment)
                segment = []
                out.append(self._monotonic(fix, fix.t_s))
                continue
            rx_u = self._unwrap(rx)
            offset = fix.t_s - rx_u
            if self._is_jump(rx_u, offset):
                out += self._stamp_segment(segment)     # the fixes before the jump belong to the old clock
                segment = []
                self.receiver_clock_jumps += 1
                log.warning("%s: receiver clock jumped (epoch time %.3f s after %.3f s, offset %.3f s from the "
                            "window's %.3f s); time stamps re-seeded", self.name, rx_u, self._last_rx_s,
                            offset - self.offset_s, self.offset_s)
                self._window.clear()
            self._enter(rx_u, offset)
            self._last_rx_s = rx_u
            segment.append((fix, rx_u))
        return out + self._stamp_segment(segment)

    # ------------------------------------------------------------------------------------------------ internal
    def _unwrap(self, rx: float) -> float:
        rx_u = rx + self.wraps * self.period_s
        if math.isfinite(self._last_rx_s) and rx_u < self._last_rx_s - 0.5 * self.period_s:
            self.wraps += 1
            rx_u += self.period_s
        return rx_u

    def _is_jump(self, rx_u: float, offset: float) -> bool:
        if not self._window:
            return False
        return rx_u < self._last_rx_s or abs(offset - self.offset_s) > MAX_LAG_S

    def _enter(self, rx_u: float, offset: float) -> None:
        """Sliding-window minimum: the deque keeps only offsets that may still become the minimum."""
        window = self._window
        while window and window[-1][1] >= offset:
            window.pop()
        window.append((rx_u, offset))
        while window[0][0] < rx_u - WINDOW_S:
            window.popleft()

    def _stamp_segment(self, segment: list[tuple[GnssFix, float]]) -> list[GnssFix]:
        offset = self.offset_s
        return [self._monotonic(fix, rx_u + offset) for fix, rx_u in segment]

    def _monotonic(self, fix: GnssFix, t_s: float) -> GnssFix:
        if t_s < self._last_stamp_s:
            self.stamps_held += 1
            if self.stamps_held in (1, 100, 10000):
                log.info("%s: fix stamp %.3f s before the previous one (a less-delayed fix showed it late); held "
                         "at the previous stamp + %.0f ms (%d so far)", self.name, self._last_stamp_s - t_s,
                         HOLD_STEP_S * 1e3, self.stamps_held)
            t_s = self._last_stamp_s + HOLD_STEP_S
        self._last_stamp_s = t_s
        return fix if t_s == fix.t_s else dataclasses.replace(fix, t_s=t_s)
