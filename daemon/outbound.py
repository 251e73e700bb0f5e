"""What goes out: the open endpoints, our MAVLink identity on them, and STATUSTEXT under a rate limit.

Every part that sends holds this object (or one of its bound methods); nothing else owns the endpoint list."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Callable

from ahrsd.daemon import messages as msgs
from ahrsd.daemon.counters import ServiceCounters
from ahrsd.daemon.mavlink_io import Endpoint, mavlink
from ahrsd.daemon.rate_limit import TokenBucket

log = logging.getLogger(__name__)


@dataclass
class Identity:
    """Our MAVLink address. The system id follows the autopilot's (daemon.inbound) unless configured."""

    system_id: int
    component_id: int
    mav_type: int


class Outbound:
    """The endpoints and the one way to send: `send` (one endpoint or all), `statustext` (rate limited)."""

    def __init__(self, identity: Identity, counters: ServiceCounters, *, clock: Callable[[], float] = time.monotonic):
        self.identity = identity
        self.counters = counters
        self.endpoints: list[Endpoint] = []
        self.clock = clock
        # STATUSTEXT budget for non-critical texts: 5/s sustained, bursts of 10 (critical ones always go out)
        self._statustext_budget = TokenBucket(rate_per_s=5.0, burst=10)

    def send(self, msg, endpoint: Endpoint | None = None) -> None:
        """Send to one endpoint, or to all of them."""
        for ep in (endpoint,) if endpoint is not None else self.endpoints:
            ep.send(msg)

    def statustext(self, severity: int, text: str) -> None:
        """Send a STATUSTEXT to every endpoint. Texts less severe than CRITICAL are rate limited, so a peer
        flooding us with refused requests cannot make us flood the radio with answers (counted, logged)."""
        if severity > mavlink.MAV_SEVERITY_CRITICAL and not self._statustext_budget.take(self.clock()):
            self.counters.statustext_suppressed += 1
            log.debug("STATUSTEXT suppressed by the rate limit: %s", text)
            return
        log.log(logging.WARNING if severity <= mavlink.MAV_SEVERITY_WARNING else logging.INFO, "%s", text)
        self.send(msgs.statustext(severity, text))

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
