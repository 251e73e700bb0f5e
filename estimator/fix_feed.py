"""GNSS fixes merged with IMU samples in time order, for an aided estimator run over a recording.

The rule (one home for `ahrsd replay --gnss`, the magnetometer levelling and whoever else replays fixes): each
fix is offered before the first sample not earlier than its time of validity (`fix.t_s <= sample.t_s`; on a tie
the fix goes first), so the estimator never fuses a measurement from its future. A fix later than the last
sample is never offered.
"""

from __future__ import annotations

from collections.abc import Iterable

from ahrsd.core.gnss import GnssFix

from .base import GnssAidedEstimator


class GnssFixFeed:
    """Offers `fixes` (time order, on the samples' time base) to `estimator` as the samples go by: call
    `offer_until(sample.t_s)` before each `estimator.update(sample)`."""

    def __init__(self, estimator: GnssAidedEstimator, fixes: Iterable[GnssFix]):
        self._update_gnss = estimator.update_gnss
        self._fixes = iter(fixes)
        self._next = next(self._fixes, None)

    def offer_until(self, t_s: float) -> None:
        """Offer every fix not yet offered whose time of validity is not later than `t_s`."""
        while self._next is not None and self._next.t_s <= t_s:
            self._update_gnss(self._next)
            self._next = next(self._fixes, None)
