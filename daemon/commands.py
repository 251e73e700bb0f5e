"""COMMAND_LONG / COMMAND_INT dispatch with the command protocol's ACK rules (mavlink.io
en/services/command.md).

`CommandRouter.register(command_id, handler)` is the extension point: a handler gets
`(msg, ctx: CommandContext)` and returns a MAV_RESULT int or a `CommandAck`. A long-running handler returns
`CommandAck(MAV_RESULT_IN_PROGRESS, progress)` and later calls `ctx.finish(result)`.

Rules implemented here, so handlers don't repeat them:
* addressed to our component → always an ACK (unknown command → MAV_RESULT_UNSUPPORTED);
* broadcast (target_component 0) → acted on only when the handler accepts broadcasts and the daemon's policy
  allows; an unknown broadcast command is ignored silently (the autopilot answers it, not us);
* duplicates of a state-changing command (the sender re-sends when our ACK crossed its timeout) are not
  re-executed: the last ACK sent for the same (source, command, parameters) within DUPLICATE_WINDOW_S is
  repeated — the parameters as one view of COMMAND_LONG and COMMAND_INT (daemon.command_args), so a retry
  sent in the other form is a duplicate too (IN_PROGRESS while a long command runs, its final result afterwards); read-only commands
  (REQUEST_MESSAGE, GET_MESSAGE_INTERVAL) are simply answered again;
* with signing required, an unsigned state-changing command is refused with MAV_RESULT_DENIED and counted;
* the ACK carries target_system/target_component = the requester;
* a handler refuses a bad request by returning `Refused(result, reason)`: counted in `refused`, one warning
  logged and sent as STATUSTEXT (rate limited: a flooding peer can fill neither the log nor the link), ACKed
  with `result`. Handlers validate their
  input and never raise; the catch-all below is the last resort, counted in `handler_errors` (the fuzz tests
  assert it stays 0).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Any, Callable

from ahrsd.daemon.command_args import CommandArgs, Refused
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.rate_limit import TokenBucket

log = logging.getLogger(__name__)

DUPLICATE_WINDOW_S = 3.0


@dataclass(frozen=True)
class CommandAck:
    result: int
    progress: int = 0          # result_param1: % when IN_PROGRESS (255 unknown)
    result_param2: int = 0


@dataclass
class CommandContext:
    """What a handler may need: who asked and on which link (what it acts on, the handler holds itself)."""

    endpoint: Any              # the Endpoint the command arrived on
    src_system: int
    src_component: int
    broadcast: bool            # target_component was 0
    signed: bool
    is_command_int: bool
    _finish: Callable[[int, int], None] | None = None

    def progress(self, percent: int) -> None:
        """Send another IN_PROGRESS ACK with progress 0..100."""
        if self._finish:
            self._finish(mavlink.MAV_RESULT_IN_PROGRESS, int(percent))

    def finish(self, result: int) -> None:
        """Send the final ACK of a long-running command."""
        if self._finish:
            self._finish(int(result), 0)


Handler = Callable[[Any, CommandContext], "int | CommandAck | Refused | None"]


@dataclass
class _Registration:
    handler: Handler
    state_changing: bool
    accept_broadcast: bool


@dataclass
class CommandCounters:
    received: int = 0
    unsupported: int = 0
    duplicates: int = 0
    unsigned_refused: int = 0
    handler_errors: int = 0      # exceptions that escaped a handler: a bug (handlers validate and refuse)
    ignored_broadcast: int = 0
    refused: int = 0             # requests a handler refused as invalid (Refused)
    refusal_logs_suppressed: int = 0


REFUSAL_LOG_RATE_PER_S = 1.0     # refusal warnings in the log: 1/s sustained, bursts of 5
REFUSAL_LOG_BURST = 5


def command_params(msg) -> tuple[float, ...]:
    """param1..param7 as floats for both COMMAND_LONG and COMMAND_INT (daemon.command_args)."""
    return CommandArgs.of(msg).params


@dataclass
class CommandRouter:
    send_ack: Callable[[Any, Any], None]       # (endpoint, COMMAND_ACK message)
    require_signed: Callable[[], bool] = lambda: False
    statustext: Callable[[int, str], None] | None = None    # daemon.outbound: a refusal the operator should see
    accept_broadcast: bool = True
    counters: CommandCounters = field(default_factory=CommandCounters)
    clock: Callable[[], float] = time.monotonic
    _handlers: dict[int, _Registration] = field(default_factory=dict)
    _recent: dict[tuple, tuple[float, Any]] = field(default_factory=dict)
    _refusal_log: TokenBucket = field(default_factory=lambda: TokenBucket(REFUSAL_LOG_RATE_PER_S, REFUSAL_LOG_BURST))
    broadcast_notice: Any = None       # daemon.broadcast_notice.BroadcastNotice: says why a broadcast was ignored

    def register(self, command_id: int, handler: Handler, *, state_changing: bool = True,
                 accept_broadcast: bool = True) -> None:
        """Install `handler` for MAV_CMD `command_id` (replacing any previous one).

        state_changing: refused unsigned when signing is required. accept_broadcast: act on target_component 0.
        """
        self._handlers[int(command_id)] = _Registration(handler, state_changing, accept_broadcast)

    def unregister(self, command_id: int) -> None:
        self._handlers.pop(int(command_id), None)

    def registered(self) -> list[int]:
        return sorted(self._handlers)

    def handle(self, msg, endpoint, broadcast: bool) -> None:
        """One COMMAND_LONG / COMMAND_INT by the module's rules: an ignored broadcast, a repeated duplicate, an
        unsupported or unsigned command answered here; else the handler's outcome ACKed."""
        self.counters.received += 1
        cmd = int(msg.command)
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        reg = self._handlers.get(cmd)
        if broadcast and self._ignored_broadcast(reg, cmd, src):
            return
        key = (src, cmd, command_params(msg))
        if self._answered_duplicate(key, reg, endpoint):
            return

        def ack(result: int, progress: int = 0, param2: int = 0, remember: bool = True) -> None:
            message = _ack_message(cmd, result, src, progress, param2)
            if remember and result != mavlink.MAV_RESULT_TEMPORARILY_REJECTED:
                self._recent[key] = (self.clock(), message)   # what a re-sent duplicate gets
            self.send_ack(endpoint, message)

        if reg is None:
            self.counters.unsupported += 1
            ack(mavlink.MAV_RESULT_UNSUPPORTED)
            return
        signed = bool(msg.get_signed())
        if reg.state_changing and self.require_signed() and not signed:
            self.counters.unsigned_refused += 1
            self._log_refusal(cmd, src, "unsigned")
            ack(mavlink.MAV_RESULT_DENIED, remember=False)   # a signed retry must be evaluated afresh
            return
        ctx = CommandContext(endpoint, src[0], src[1], broadcast, signed,
                             msg.get_type() == "COMMAND_INT", lambda r, p: ack(r, p))
        self._ack_outcome(self._run_handler(reg, msg, ctx, cmd), ack, cmd, src)

    def _ignored_broadcast(self, reg: _Registration | None, cmd: int, src: tuple[int, int]) -> bool:
        """A broadcast we do not act on (not ours, not accepted by its handler or by the daemon's policy): counted,
        and said when the command is ours."""
        if reg is not None and reg.accept_broadcast and self.accept_broadcast:
            return False
        self.counters.ignored_broadcast += 1
        if reg is not None and self.broadcast_notice is not None:
            self.broadcast_notice.note(cmd, src)    # ours, but not on a broadcast: say so
        return True

    def _answered_duplicate(self, key: tuple, reg: _Registration | None, endpoint) -> bool:
        """A state-changing (or unknown) command seen within DUPLICATE_WINDOW_S: its last ACK sent again."""
        now = self.clock()
        self._expire(now)
        previous = self._recent.get(key) if reg is None or reg.state_changing else None
        if previous is None:
            return False
        self.counters.duplicates += 1
        self._recent[key] = (now, previous[1])
        self.send_ack(endpoint, previous[1])
        return True

    def _run_handler(self, reg: _Registration, msg, ctx: CommandContext, cmd: int):
        """The handler's outcome; one that raised (a bug: handlers refuse, never raise) is FAILED, counted."""
        try:
            return reg.handler(msg, ctx)
        except Exception:  # noqa: BLE001 - a failing handler answers FAILED, the daemon carries on
            self.counters.handler_errors += 1
            log.exception("command %d handler failed", cmd)
            return mavlink.MAV_RESULT_FAILED

    def _ack_outcome(self, out, ack: Callable[..., None], cmd: int, src: tuple[int, int]) -> None:
        """ACK a handler's outcome: None (it answers later through ctx.finish), Refused, CommandAck or a result."""
        if out is None:
            return
        if isinstance(out, Refused):
            self.counters.refused += 1
            self._log_refusal(cmd, src, out.reason, tell_operator=True)
            ack(out.result)
        elif isinstance(out, CommandAck):
            ack(out.result, out.progress, out.result_param2)
        else:
            ack(int(out))

    def _log_refusal(self, cmd: int, src: tuple[int, int], reason: str, tell_operator: bool = False) -> None:
        """One warning per refusal, rate limited (a flooding peer can fill neither the log nor the link)."""
        if not self._refusal_log.take(self.clock()):
            self.counters.refusal_logs_suppressed += 1
            return
        log.warning("command %d from %d/%d refused: %s", cmd, src[0], src[1], reason)
        if tell_operator and self.statustext is not None:      # the operator sees why, not only the MAV_RESULT
            self.statustext(mavlink.MAV_SEVERITY_WARNING, f"ahrsd: {reason}")

    def _expire(self, now: float) -> None:
        if len(self._recent) > 64 or self._recent:
            stale = [k for k, (t, _) in self._recent.items() if now - t > DUPLICATE_WINDOW_S]
            for k in stale:
                del self._recent[k]


def _ack_message(command: int, result: int, src: tuple[int, int], progress: int, param2: int):
    return mavlink.MAVLink_command_ack_message(command, result, progress, param2, src[0], src[1])
