"""What goes out: the open endpoints, our MAVLink identity on them, and STATUSTEXT under a rate limit.

Every part that sends holds this object (or one of its bound methods); nothing else owns the endpoint list.
`statustext` is the one place a STATUSTEXT is sent: a text longer than one message (50 bytes) goes out as MAVLink
2 chunks (common.xml STATUSTEXT `id`, `chunk_seq`; daemon.messages.statustext_chunks).

How a chunked text counts against the rate limit: one text is one token, and all its chunks go out together or
none does. A receiver shows a text only once it has every chunk, and shows a gap as " ... " otherwise (MAVProxy
mavproxy_link.py emits a pending text 1 s after its last chunk; QGroundControl's StatusTextHandler closes a pending
text as incomplete as soon as another STATUSTEXT of the same component arrives), so a text is never cut. Charging
one token per chunk would let a flood of short refusals keep the bucket below the chunk count of a long text
forever, so the daemon's own long texts (heading state, MAV_STATE, mag-cal results) would never go out; the bytes
per token stay bounded because every text is written by the daemon and is a few chunks long (a peer's input
appears in it only as a short field: a parameter name, a number). All chunks of one text are sent in one call, so no other
STATUSTEXT of ours comes between them, and an endpoint takes them all or none (`Endpoint.send_together`: a serial
link too full for every chunk sends none of them)."""

from __future__ import annotations

import logging
import time
from collections import deque
from dataclasses import dataclass
from typing import Callable, Protocol

from ahrsd.daemon import messages as msgs
from ahrsd.daemon.counters import ServiceCounters
from ahrsd.daemon.mavlink_io import Endpoint, mavlink
from ahrsd.daemon.rate_limit import TokenBucket

log = logging.getLogger(__name__)

SENT_TEXTS_KEPT = 64     # the latest texts sent, for a reader (a test, a diagnosis): `Outbound.sent_texts`


class OutboundEndpoint(Protocol):
    """What Outbound needs of an endpoint (daemon.mavlink_io.Endpoint; a test's stand-in)."""

    def send(self, msg) -> bool: ...
    def send_together(self, msgs) -> bool: ...     # all of them or none (the chunks of one STATUSTEXT)


@dataclass
class Identity:
    """Our MAVLink address. The system id follows the autopilot's (daemon.inbound) unless configured."""

    system_id: int
    component_id: int
    mav_type: int


class Outbound:
    """The endpoints and the one way to send: `send` (one endpoint or all), `statustext` (rate limited; the latest
    texts sent kept in `sent_texts`)."""

    def __init__(self, identity: Identity, counters: ServiceCounters, *, clock: Callable[[], float] = time.monotonic):
        self.identity = identity
        self.counters = counters
        self.endpoints: list[OutboundEndpoint] = []
        self.clock = clock       # the daemon's clock (Service.clock): the rate limit runs on it
        # STATUSTEXT budget for non-critical texts: 5 texts/s sustained, bursts of 10 (critical ones always go out)
        self._statustext_budget = TokenBucket(rate_per_s=5.0, burst=10)
        self._chunk_id = 0       # the id of the latest chunked text (1..65535; 0 means "not chunked")
        self.sent_texts: deque[tuple[int, str]] = deque(maxlen=SENT_TEXTS_KEPT)   # (severity, text), latest last

    def send(self, msg, endpoint: Endpoint | None = None) -> None:
        """Send to one endpoint, or to all of them."""
        for ep in (endpoint,) if endpoint is not None else self.endpoints:
            ep.send(msg)

    def statustext(self, severity: int, text: str) -> None:
        """Send `text` (any length: chunked when longer than one STATUSTEXT) to every endpoint, and log it. Texts
        less severe than CRITICAL are rate limited, one token per text, so a peer flooding us with refused requests
        cannot make us flood the radio with answers (counted, logged at debug)."""
        if severity > mavlink.MAV_SEVERITY_CRITICAL and not self._statustext_budget.take(self.clock()):
            self.counters.statustext_suppressed += 1
            log.debug("STATUSTEXT suppressed by the rate limit: %s", text)
            return
        log.log(logging.WARNING if severity <= mavlink.MAV_SEVERITY_WARNING else logging.INFO, "%s", text)
        self.sent_texts.append((severity, text))
        chunks = msgs.statustext_chunks(severity, text, self._chunk_id % 65535 + 1)
        if len(chunks) > 1:
            self._chunk_id = chunks[0].id
        for ep in self.endpoints:
            ep.send_together(chunks)

    def set_system_id(self, system_id: int) -> None:
        """Adopt the autopilot's system id on every endpoint (daemon.inbound)."""
        self.identity.system_id = system_id
        for ep in self.endpoints:
            ep.set_system_id(system_id)

    def link_totals(self) -> dict:
        tx = sum(ep.counters.tx_messages for ep in self.endpoints)
        rx = sum(ep.counters.rx_messages for ep in self.endpoints)
        bad = sum(ep.counters.rx_malformed + ep.counters.rx_bad_signature for ep in self.endpoints)
        return {"tx": tx, "rx": rx, "bad": bad}

    def comm_errors(self) -> int:
        return sum(e.counters.rx_malformed + e.counters.rx_bad_signature for e in self.endpoints)
