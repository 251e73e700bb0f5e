"""TIMESYNC requests (`tc1 = 0`) answered, at most ANSWERS_PER_S per sender.

Who asks, and how often: PX4 sends TIMESYNC requests at 10 Hz on an onboard link, MAVROS at its `timesync_rate`
(10 Hz by default), MAVSDK every 5 s. ArduPilot and PX4 themselves answer every request they receive (ArduPilot
GCS_MAVLINK::handle_timesync drops an answer only when the link has no room for it, HAVE_PAYLOAD_SPACE; PX4
MavlinkTimesync::handle_message answers unconditionally), which bounds the answers by the link on a radio but not
on UDP, where a flooding or broken peer makes us send one answer per request (bench/latency.py's flood, docs/daemon.md).
So each sender — system and component id, on one endpoint — may have ANSWERS_PER_S answers a second with
bursts of BURST: twice the fastest requester above, so no real requester ever loses an answer. A request beyond
that is not answered: counted (`timesync_refused`, the stats file's "service" section, beside the answered ones,
`timesync_answered`), and logged — a warning at a sender's first refusal, then at most once every LOG_EVERY_S
with how many since.

A hostile peer can forge any number of sender ids: at most MAX_SENDERS are followed one by one, the requests of
any further sender share one limit.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

from ahrsd.daemon import messages as msgs
from ahrsd.daemon.counters import ServiceCounters
from ahrsd.daemon.rate_limit import TokenBucket

log = logging.getLogger(__name__)

ANSWERS_PER_S = 20.0
BURST = 20
LOG_EVERY_S = 60.0
MAX_SENDERS = 32
OTHER_SENDERS = (None, -1, -1)     # the key of the shared limit once MAX_SENDERS are followed


@dataclass
class _Sender:
    budget: TokenBucket = field(default_factory=lambda: TokenBucket(rate_per_s=ANSWERS_PER_S, burst=BURST))
    refused_since_log: int = 0
    logged_at_s: float | None = None


class TimesyncAnswers:
    """`on_request(endpoint, msg, now_s)`: answer a TIMESYNC request on its endpoint, within its sender's limit."""

    def __init__(self, counters: ServiceCounters):
        self.counters = counters
        self._senders: dict[tuple, _Sender] = {}

    def on_request(self, endpoint, msg, now_s: float) -> None:
        key = (id(endpoint), msg.get_srcSystem(), msg.get_srcComponent())
        sender = self._senders.get(key)
        if sender is None:
            if len(self._senders) >= MAX_SENDERS:
                key = OTHER_SENDERS
                sender = self._senders.get(key)
            if sender is None:
                sender = self._senders[key] = _Sender()
        if sender.budget.take(now_s):
            endpoint.send(msgs.timesync_reply(endpoint.timesync_stamp_ns(), msg.ts1))
            self.counters.timesync_answered += 1
            return
        self.counters.timesync_refused += 1
        sender.refused_since_log += 1
        if sender.logged_at_s is None or now_s - sender.logged_at_s >= LOG_EVERY_S:
            who = "senders beyond the first %d" % MAX_SENDERS if key is OTHER_SENDERS else "%d/%d" % key[1:]
            log.warning("TIMESYNC requests from %s faster than %g/s: %d not answered%s", who, ANSWERS_PER_S,
                        sender.refused_since_log,
                        "" if sender.logged_at_s is None else " in the last %.0f s" % (now_s - sender.logged_at_s))
            sender.refused_since_log = 0
            sender.logged_at_s = now_s
