"""Message rates: one absolute-deadline schedule per output (daemon.output_registry), settable at run time.

Intervals follow MAV_CMD_SET_MESSAGE_INTERVAL semantics (common.xml): interval in µs, −1 disables, 0 restores
the configured default. Deadlines are absolute (`due += interval`), so rates do not drift with scheduling
jitter; a wake up to CATCH_UP_LIMIT_S late catches up, after a longer stall the schedule restarts from now
instead of bursting. The deadlines a restart skips are counted per stream (`dropped_slots`) and the latest
restarts kept (`skips`): a message not sent because the daemon was not given the CPU is accounted for. A deadline
served with nothing to send is counted too, by the publishers (`held`): `withheld_slots` when there was nothing
trustworthy to send (VISION_POSITION_ESTIMATE while the heading is not trusted or UNKNOWN; any output of the
estimate while samples do not flow), `unchanged_slots` when a once-per-estimate output had no new estimate since
the last one sent; runs of them with their times are kept (`held_runs`). So the slots sent + held + dropped are
the deadlines that passed whatever the load and the heading (the run stats, daemon.run_stats).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from ahrsd.daemon.output_registry import BY_MESSAGE_ID, DEFAULT_MAX_RATE_HZ

CATCH_UP_LIMIT_S = 0.25   # a late wake sends what fell due (rates stay exact); a longer stall does not burst
SKIPS_KEPT = 1000         # restarts remembered with their times (a bounded record; the counts are never bounded)
HELD_RUNS_KEPT = 1000     # runs of held deadlines remembered with their times (bounded likewise)
WITHHELD, UNCHANGED = "withheld", "unchanged"    # why a served deadline sent nothing (OutputSchedule.held)


@dataclass
class _Stream:
    default_hz: float
    rate_hz: float
    due: float = 0.0
    dropped_slots: int = 0     # deadlines skipped by restarts after a long stall
    served: int = 0            # deadlines `due` returned (sent or held)
    withheld_slots: int = 0    # served with nothing trustworthy to send (OutputSchedule.held)
    unchanged_slots: int = 0   # served when the once-per-estimate output had no new estimate
    held_run: HeldRun | None = None     # the latest run of held deadlines (extended while they follow each other)


@dataclass(frozen=True)
class Skip:
    """One restart: `count` deadlines of `message_id`, the first at `first_due_s` (the daemon's clock), then
    every `period_s`, were skipped."""
    message_id: int
    first_due_s: float
    period_s: float
    count: int


@dataclass
class HeldRun:
    """Consecutive served deadlines of `message_id` that sent nothing for one `reason` (WITHHELD, UNCHANGED):
    `count` of them, served from `first_s` to `last_s` (the daemon's clock, at the wakes that served them)."""
    message_id: int
    reason: str
    first_s: float
    last_s: float
    count: int
    served_after: int      # the stream's `served` after the last one: the next held deadline continues the run


class OutputSchedule:
    def __init__(self, rates_hz: dict[int, float]):
        self._streams = {mid: _Stream(hz, hz) for mid, hz in rates_hz.items()}
        self._next_due = 0.0   # earliest deadline of all streams: most per-sample calls return at once
        self.skips: deque[Skip] = deque(maxlen=SKIPS_KEPT)
        self.held_runs: deque[HeldRun] = deque(maxlen=HELD_RUNS_KEPT)

    def __contains__(self, message_id: int) -> bool:
        return message_id in self._streams

    def ids(self):
        return self._streams.keys()

    def rate_hz(self, message_id: int) -> float:
        return self._streams[message_id].rate_hz

    def dropped_slots(self) -> dict[int, int]:
        """Per stream, the deadlines skipped by restarts since the start (never sent, never due again)."""
        return {mid: s.dropped_slots for mid, s in self._streams.items()}

    def served_slots(self) -> dict[int, int]:
        """Per stream, the deadlines `due` returned since the start: each was sent or counted `held`."""
        return {mid: s.served for mid, s in self._streams.items()}

    def withheld_slots(self) -> dict[int, int]:
        """Per stream, the served deadlines that sent nothing trustworthy (`held` WITHHELD) since the start."""
        return {mid: s.withheld_slots for mid, s in self._streams.items()}

    def unchanged_slots(self) -> dict[int, int]:
        """Per stream, the served deadlines of a once-per-estimate output with no new estimate (`held` UNCHANGED)."""
        return {mid: s.unchanged_slots for mid, s in self._streams.items()}

    def held(self, message_id: int, now: float, reason: str) -> None:
        """The deadline of `message_id` that `due(now)` just returned sends nothing, for `reason`: counted, and kept
        in the latest run of held deadlines (a new run when a deadline between was sent or held for another
        reason)."""
        s = self._streams[message_id]
        if reason == WITHHELD:
            s.withheld_slots += 1
        else:
            s.unchanged_slots += 1
        run = s.held_run
        if run is not None and run.reason == reason and run.served_after == s.served - 1:
            run.last_s = now
            run.count += 1
            run.served_after = s.served
        else:
            s.held_run = HeldRun(message_id, reason, now, now, 1, s.served)
            self.held_runs.append(s.held_run)

    def max_rate_hz(self, message_id: int) -> float:
        spec = BY_MESSAGE_ID.get(message_id)
        return DEFAULT_MAX_RATE_HZ if spec is None else spec.max_rate_hz

    def set_rate_hz(self, message_id: int, hz: float, *, default: bool = False) -> None:
        s = self._streams[message_id]
        if not 0.0 <= hz <= self.max_rate_hz(message_id):
            raise ValueError(f"rate {hz:g} Hz outside [0, {self.max_rate_hz(message_id):g}]")
        s.rate_hz = hz
        s.due = 0.0
        self._next_due = 0.0
        if default:
            s.default_hz = hz

    def set_interval_us(self, message_id: int, interval_us: float) -> None:
        """SET_MESSAGE_INTERVAL: −1 off, 0 default, else the interval in µs. Raises ValueError if out of range."""
        if interval_us == -1:
            self.set_rate_hz(message_id, 0.0)
        elif interval_us == 0:
            self.set_rate_hz(message_id, self._streams[message_id].default_hz)
        elif interval_us > 0:
            self.set_rate_hz(message_id, 1e6 / interval_us)
        else:
            raise ValueError(f"interval {interval_us:g} µs is neither −1, 0 nor positive")

    def interval_us(self, message_id: int) -> int:
        """MESSAGE_INTERVAL.interval_us: −1 when disabled."""
        hz = self._streams[message_id].rate_hz
        return -1 if hz <= 0.0 else int(round(1e6 / hz))

    @property
    def next_due(self) -> float:
        """The earliest deadline of the streams as of the last `due` call (0.0 after a rate change: look now;
        inf: every stream off)."""
        return self._next_due

    def due(self, now: float) -> list[int]:
        """Messages whose deadline has come; advances their deadlines."""
        if now < self._next_due:
            return []
        out = []
        next_due = float("inf")
        for mid, s in self._streams.items():
            if s.rate_hz <= 0.0:
                continue
            if s.due == 0.0:
                s.due = now
            if now >= s.due:
                out.append(mid)
                s.served += 1
                period = 1.0 / s.rate_hz
                s.due += period
                if now - s.due > CATCH_UP_LIMIT_S:    # a long stall: restart instead of bursting
                    # the deadlines s.due, s.due + period, … ≤ now are skipped; now + period stands in for the
                    # one deadline in (now, now + period]
                    skipped = int((now - s.due) // period) + 1
                    s.dropped_slots += skipped
                    self.skips.append(Skip(mid, s.due, period, skipped))
                    s.due = now + period
            next_due = min(next_due, s.due)
        self._next_due = next_due
        return out
