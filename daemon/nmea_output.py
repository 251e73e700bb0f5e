"""The NMEA 0183 outputs: each `[[nmea]]` output sends its sentences at their rates from the estimates as they
come (docs/marine.md). A part of the daemon with one input, `on_estimate(estimate)`, called after every sample;
it owns its transports and counters and needs nothing else.

Scheduling follows the estimates' own sample times (`t_s`), not the host clock: a sentence is due every
1/rate seconds of sample time, so a replay at any speed and a test with a stepped clock send exactly the
configured rates.
"""

from __future__ import annotations

import logging
import math

from ahrsd.core.estimate import AttitudeEstimate
from ahrsd.daemon.nmea_sentences import HEADING_SENTENCES, build_sentence, heading_known
from ahrsd.daemon.nmea_transport import open_transport

log = logging.getLogger(__name__)


class NmeaOutput:
    """One output: a transport, a talker ID and the sentences that are on (name → Hz)."""

    def __init__(self, transport, talker: str, rates_hz: dict[str, float]):
        self.transport = transport
        self.talker = talker
        self.rates_hz = {name: hz for name, hz in rates_hz.items() if hz > 0.0}
        self._next_due_s = {name: -math.inf for name in self.rates_hz}
        self.sent = {name: 0 for name in self.rates_hz}
        self.withheld = {name: 0 for name in self.rates_hz}   # due while the heading (or attitude) was unknown

    @property
    def description(self) -> str:
        return self.transport.description

    def on_estimate(self, est: AttitudeEstimate) -> None:
        for name, hz in self.rates_hz.items():
            due = self._next_due_s[name]
            if est.t_s < due:
                continue
            period = 1.0 / hz
            # The next slot on the rate's grid; after a gap (or at the start) from this sample on.
            self._next_due_s[name] = due + period if est.t_s - due < period else est.t_s + period
            sentence = build_sentence(name, est, self.talker)
            if sentence is None:
                self.withheld[name] += 1
                continue
            if self.transport.send(sentence):
                self.sent[name] += 1

    def next_due_s(self) -> float:
        """The sample time at which a sentence falls due next (inf: none yet, before the first estimate)."""
        return min((t for t in self._next_due_s.values() if t > -math.inf), default=math.inf)

    def counters(self) -> dict:
        return {"sent": dict(self.sent), "withheld": dict(self.withheld), **self.transport.counters.as_dict()}

    def close(self) -> None:
        self.transport.close()


class NmeaOutputs:
    """Every configured output; the daemon's part. `configs` are daemon.config.NmeaOutputConfig."""

    def __init__(self, configs, open_transport_fn=open_transport):
        self.outputs = [NmeaOutput(open_transport_fn(cfg.url), cfg.talker, cfg.rates_hz) for cfg in configs]
        self._heading_was_known: bool | None = None

    def open(self, loop) -> None:
        """Start serving on the event loop (TCP servers bind here: an error names the output)."""
        for out in self.outputs:
            out.transport.open(loop)
            log.info("NMEA 0183 output %s: talker %s, %s", out.description, out.talker,
                     ", ".join(f"{n} {hz:g} Hz" for n, hz in out.rates_hz.items()))

    def on_estimate(self, est: AttitudeEstimate) -> None:
        known = heading_known(est)
        if known != self._heading_was_known and any(HEADING_SENTENCES & out.rates_hz.keys()
                                                    for out in self.outputs):
            log.info("NMEA heading sentences %s", "sent" if known else "withheld: heading unknown")
            self._heading_was_known = known
        for out in self.outputs:
            out.on_estimate(est)

    def next_due_s(self) -> float:
        """The sample time at which a sentence of any output falls due next (inf: none)."""
        return min((out.next_due_s() for out in self.outputs), default=math.inf)

    def counters(self) -> dict:
        return {out.description: out.counters() for out in self.outputs}

    def close(self) -> None:
        for out in self.outputs:
            out.close()
