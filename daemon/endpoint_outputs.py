"""Per-endpoint outputs: each endpoint has its own schedule, built from its profile and overrides
(daemon.output_profiles), and a serial endpoint a byte budget checked at start and after every rate change
(daemon.link_budget) and a non-blocking priority queue (daemon.serial_queue).

Rates: the daemon-wide rate of an output (`[outputs]`, the `SR_*` parameters) applies to every endpoint whose
profile includes it and that has no override for it; SET_MESSAGE_INTERVAL changes only the endpoint the
request came in on.
"""

from __future__ import annotations

import logging
from typing import Callable

from ahrsd.daemon.config import EndpointConfig
from ahrsd.daemon.link_budget import LinkBudget, line_bytes_per_s, priority_of
from ahrsd.daemon.mavlink_io import Endpoint, mavlink
from ahrsd.daemon.outbound import Outbound
from ahrsd.daemon.output_profiles import endpoint_rates_hz, follows_base_rate
from ahrsd.daemon.outputs import OutputSchedule

log = logging.getLogger(__name__)


class EndpointOutputs:
    """`make_endpoint`, `set_output_rate_hz` (SR_*), `set_message_interval` (one endpoint), `check_link_budget`.

    `base_rates_hz()` gives the daemon-wide rate of every output (the SR_* parameters); `signed()` whether
    frames carry a signature (for the byte budget); `warn_soon(severity, text)` schedules a STATUSTEXT."""

    def __init__(self, outbound: Outbound, *, base_rates_hz: Callable[[], dict[int, float]],
                 signed: Callable[[], bool], warn_soon: Callable[[int, str], None]):
        self.outbound = outbound
        self.base_rates_hz = base_rates_hz
        self.signed = signed
        self.warn_soon = warn_soon

    def make_endpoint(self, ep_cfg: EndpointConfig, on_message: Callable) -> Endpoint:
        identity = self.outbound.identity
        ep = Endpoint(ep_cfg.url, identity.system_id, identity.component_id, on_message)
        ep.profile = ep_cfg.profile
        ep.overrides_hz = ep_cfg.overrides_hz
        ep.schedule = OutputSchedule(endpoint_rates_hz(ep.profile, ep.overrides_hz, self.base_rates_hz()))
        baud = ep_cfg.serial_baud
        if baud is not None:
            ep.line_bytes_per_s = line_bytes_per_s(baud)
            ep.priority_of = priority_of
            ep.budget = LinkBudget(ep.url, baud)
        else:
            ep.budget = None
        return ep

    def set_output_rate_hz(self, message_id: int, hz: float) -> None:
        """The daemon-wide rate (SR_* parameter): every endpoint that follows it. Raises ValueError."""
        endpoints = self.outbound.endpoints
        for ep in endpoints:
            if follows_base_rate(ep.profile, ep.overrides_hz, message_id):
                ep.schedule.set_rate_hz(message_id, hz, default=True)
        for ep in endpoints:
            self.check_link_budget(ep)

    def set_message_interval(self, endpoint: Endpoint, message_id: int, interval_us: float) -> None:
        """MAV_CMD_SET_MESSAGE_INTERVAL on the endpoint it came in on. Raises ValueError if out of range."""
        endpoint.schedule.set_interval_us(message_id, interval_us)
        self.check_link_budget(endpoint)

    @staticmethod
    def endpoint_rates_hz(endpoint: Endpoint) -> dict[int, float]:
        return {mid: endpoint.schedule.rate_hz(mid) for mid in endpoint.schedule.ids()}

    def check_link_budget(self, endpoint: Endpoint) -> None:
        """Serial endpoints: warn once (log + STATUSTEXT) when the outputs need more than 80 % of the line."""
        budget = endpoint.budget
        if budget is None:
            return
        text = budget.check(self.endpoint_rates_hz(endpoint), signed=self.signed())
        if text is not None:
            log.warning("%s", text)
            self.warn_soon(mavlink.MAV_SEVERITY_WARNING, f"ahrsd: link {100 * budget.fraction:.0f}% full, see log")
