"""The publishers: each output of daemon.output_registry that falls due is built from the latest estimate and
sample and sent to the endpoints whose own schedule (daemon.endpoint_outputs) has it due; SYS_STATUS and HEARTBEAT from the health and the counters."""

from __future__ import annotations

from ahrsd.daemon import messages as msgs
from ahrsd.daemon.output_registry import BY_MESSAGE_ID
from ahrsd.daemon.run_stats import sample_accounting


class Publishers:
    """Service part: `_publish` (every reader wake), `build_output` (REQUEST_MESSAGE), SYS_STATUS, HEARTBEAT."""

    def _publish(self, now: float) -> None:
        """Send what fell due on each endpoint's own schedule; a message due on several endpoints at once is
        built once."""
        built = None
        for ep in self.endpoints:
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
                    m = None if spec.needs_estimate and not fresh else spec.build(self, est, sample, now)
                    built[mid] = m
                if m is not None and ep.send(m):
                    self.counters.published += 1

    def build_output(self, mid: int, now: float):
        """The output message `mid` from the current state (REQUEST_MESSAGE), or None if it cannot be sent."""
        spec = BY_MESSAGE_ID[mid]
        est = self.pipeline.last_estimate
        if spec.needs_estimate and est is None:
            return None
        return spec.build(self, est, self.pipeline.last_sample, now)

    def sys_status_message(self, now: float):
        present, enabled, healthy = self.health.sensor_bits(now)
        if self.gnss is not None:
            present, enabled, healthy = (a | b for a, b in zip((present, enabled, healthy),
                                                                self.gnss.sensor_bits(now)))
        links = self.endpoints
        errors_comm = sum(e.counters.rx_malformed + e.counters.rx_bad_signature for e in links)
        unsigned = self.commands.counters.unsigned_refused + self.counters.unsigned_refused
        acc = sample_accounting(self)             # missed, late, corrupt (+ bus failures) samples
        return msgs.sys_status(present, enabled, healthy, self.load_permille, errors_comm,
                               (unsigned, acc["missed"], acc["late"], acc["corrupt"] + self.counters.driver_errors))

    def _send_heartbeat(self, now: float) -> None:
        self.send(msgs.heartbeat(self.mav_type, self.health.system_status(now)))
