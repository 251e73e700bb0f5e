"""The part of an aided filter's GNSS counters the daemon's GNSS task watches (estimator.ins.GnssCounters), for
the fake aided estimators of the GNSS tests."""

from __future__ import annotations

import dataclasses


@dataclasses.dataclass
class GateCounters:
    offered: int = 0
    rejected_velocity: int = 0

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)
