"""The publishers: each output of daemon.output_registry that falls due is built from the latest estimate and
sample and sent to the endpoints whose own schedule (daemon.endpoint_outputs) has it due. A due deadline that
sends nothing is told to the schedule with its reason (daemon.outputs: WITHHELD, UNCHANGED), so the deadlines
add up: sent + held + dropped."""

from __future__ import annotations

import math

from ahrsd.daemon.counters import ServiceCounters
from ahrsd.daemon.health import Health
from ahrsd.daemon.output_registry import BY_MESSAGE_ID, OutputContext
from ahrsd.daemon.outbound import Outbound
from ahrsd.daemon.outputs import UNCHANGED, WITHHELD
from ahrsd.daemon.pipeline import Pipeline


class Publishers:
    """`publish(now)` (every reader wake) and `build_output` (REQUEST_MESSAGE)."""

    def __init__(self, outbound: Outbound, pipeline: Pipeline, health: Health, counters: ServiceCounters,
                 context: OutputContext):
        self.outbound = outbound
        self.pipeline = pipeline
        self.health = health
        self.counters = counters
        self.context = context
        self._sent_estimate_t_s: dict[tuple[int, int], float] = {}   # (endpoint, message id) → estimate time sent

    def publish(self, now: float) -> None:
        """Send what fell due on each endpoint's own schedule; a message due on several endpoints at once is
        built once."""
        built = None
        for ep in self.outbound.endpoints:
            due = ep.schedule.due(now)
            if not due:
                continue
            if built is None:
                built = {}
                est = self.pipeline.last_estimate
                sample = self.pipeline.last_sample
                fresh = self.health.samples_flowing(now) and not self.health.sensor_error and est is not None
            for mid in due:
                if mid in built:
                    m = built[mid]
                else:
                    spec = BY_MESSAGE_ID[mid]
                    m = None if spec.needs_estimate and not fresh else spec.build(self.context, est, sample, now)
                    built[mid] = m
                if m is None:
                    ep.schedule.held(mid, now, WITHHELD)    # nothing trustworthy to send now
                    continue
                if BY_MESSAGE_ID[mid].once_per_estimate:
                    key = (id(ep), mid)
                    if self._sent_estimate_t_s.get(key) == est.t_s:
                        ep.schedule.held(mid, now, UNCHANGED)   # no new estimate since the one sent
                        continue
                    self._sent_estimate_t_s[key] = est.t_s
                if ep.send(m):
                    self.counters.published += 1

    def next_due(self) -> float:
        """When an output falls due next on any endpoint (the clock of `publish`; inf: none)."""
        return min((ep.schedule.next_due for ep in self.outbound.endpoints), default=math.inf)

    def build_output(self, mid: int, now: float):
        """The output message `mid` from the current state (REQUEST_MESSAGE), or None if it cannot be sent."""
        spec = BY_MESSAGE_ID[mid]
        est = self.pipeline.last_estimate
        if spec.needs_estimate and est is None:
            return None
        return spec.build(self.context, est, self.pipeline.last_sample, now)
