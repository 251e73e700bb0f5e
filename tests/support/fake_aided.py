"""A fake aided estimator for the GNSS tests (the daemon's GNSS task and replay --gnss), and the part of an aided
filter's GNSS counters the daemon's GNSS task watches (estimator.ins.GnssCounters)."""

from __future__ import annotations

import dataclasses

import numpy as np

from ahrsd.core.estimate import AttitudeEstimate, EstimateFlags, NavState


@dataclasses.dataclass
class GateCounters:
    offered: int = 0
    rejected_velocity: int = 0

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


class WithoutLeverArmCheck:
    """The lever-arm part of an aided estimator (estimator.base.GnssAidedEstimator) for the fakes: the antenna told
    at the IMU, and no lever-arm check to say anything or adopt an arm."""

    lever_arm_m = (0.0, 0.0, 0.0)

    def lever_arm_fit(self):
        return None    # the lever-arm check has nothing to say

    def lever_arm_adopted_m(self):
        return None    # nor adopted an arm


class FakeAided(WithoutLeverArmCheck):
    """An 'aided' estimator (it has update_gnss): a fixed attitude, records the fixes it is offered, and a
    navigation state once it has one. `flags` is what its estimates carry."""

    name = "fake-aided"

    def __init__(self):
        self.fixes = []
        self.flags = EstimateFlags.NONE
        self.gnss_counters = GateCounters()

    def update_gnss(self, fix):
        self.fixes.append(fix)
        return 0

    def update(self, sample):
        nav = None
        if self.fixes:
            f = self.fixes[-1]
            nav = NavState(np.array([1.5, -2.0, 0.25]), f.lat_deg, f.lon_deg, f.alt_m, np.full(3, 0.1),
                           np.full(3, 1.0), np.zeros(3))
        return AttitudeEstimate(sample.t_s, np.array([1.0, 0, 0, 0]), 0.0, 0.0, 0.0, 0.0, 0.0, np.zeros(3),
                                np.zeros(3), np.full(3, 0.01), self.flags, nav)

    def reset(self):
        pass

    def set_declination(self, rad):
        pass

    def relearn_field_reference(self, heading_change_rad=float("nan")):
        pass
