"""An estimator that answers every sample with an estimate carrying no flags: for tests of the reader's wakes and
hand-overs, where what the estimator computes does not matter."""

from __future__ import annotations

from ahrsd.core.estimate import EstimateFlags


class StubEstimate:
    flags = EstimateFlags.NONE


class StubEstimator:
    def update(self, sample):
        return StubEstimate()
