"""The GNSS velocities an aided filter rejected, counted by their cause as each sample's estimate goes by
(`RejectionWatch`): the heading's, as estimator/velocity_rejection_cause.py names it (the daemon's rule), or
UNEXPLAINED — the rejections the heading cannot explain, which leave the antenna's lever arm and the fixes' time
stamps. Read by the offline levelling's warning (calibration/mag/levelling_rejections.py, `calibrate mag --gnss`)
and by `ahrsd replay --gnss`'s summary (cli/replay.py), so both say what the daemon says."""

from __future__ import annotations

import math

from ahrsd.core.estimate import HeadingState

from .velocity_rejection_cause import YAW_RESET_CAUSE_S, heading_rejection_cause

UNEXPLAINED = "unexplained"    # a rejected velocity the heading does not explain (RejectionWatch.by_cause)
HEADING_CAUSE_WORDS = {      # velocity_rejection_cause.py's keys, as a warning says them
    "iron step": "after the magnetometer's iron stepped",
    "mag disagrees": "while the magnetometer disagreed with the GNSS yaw",
    "heading reset": f"within {YAW_RESET_CAUSE_S:g} s of a reset of its yaw to the GNSS yaw",
    "heading unknown": "before its heading was found",
}


class RejectionWatch:
    """The GNSS velocities an aided filter (`est`: ins, or the smoother around it) rejected, counted by their cause
    (`by_cause`): the heading's as velocity_rejection_cause.py names it, or UNEXPLAINED. `mag_enabled`: the filter
    weighs a magnetometer (its heading checks' states then say whether they rejected it). Called with each sample's
    estimate."""

    def __init__(self, est, mag_enabled: bool):
        self.est, self.mag_enabled = est, mag_enabled
        self.by_cause: dict[str, int] = {}
        self._rejected = 0
        self._yaw_resets = 0
        self._reset_at_s = -math.inf

    def __call__(self, e) -> None:
        est = self.est
        if est.yaw_resets != self._yaw_resets:
            self._yaw_resets, self._reset_at_s = est.yaw_resets, e.t_s
        new = est.gnss_counters.rejected_velocity - self._rejected
        if new <= 0:
            return
        self._rejected += new
        integrity = e.integrity
        state = HeadingState(e.heading_state)
        fit = est.lever_arm_fit()
        cause = heading_rejection_cause(
            iron_step_rad=integrity.mag_step_rad if integrity is not None else math.nan,
            # the magnetometer this filter weighs was rejected by its heading checks
            mag_inconsistent=self.mag_enabled and state in (HeadingState.GNSS_ONLY, HeadingState.LEARNING),
            disagreement_rad=(integrity.mag_disagreement_rad if integrity is not None and integrity.gsf_valid
                              else math.nan),
            since_yaw_reset_s=e.t_s - self._reset_at_s,
            # the estimator's own bound of an UNKNOWN heading, on its yaw σ: a filter without a magnetometer
            # publishes no heading state of its own (UNKNOWN throughout), its yaw σ says when the GNSS found it
            heading_unknown=bool(e.sigma_rpy_rad[2] > self.est.params.heading_unknown_sigma_rad),
            # the latch, as the heading reads it (lever_arm_fit.py heading_bent), not the momentary fit
            lever_arm_explains=fit is not None and fit.heading_bent)
        key = UNEXPLAINED if cause is None else cause.key
        self.by_cause[key] = self.by_cause.get(key, 0) + new


def heading_explained(by_cause: dict[str, int]) -> dict[str, int]:
    """Of the rejections counted by cause (RejectionWatch.by_cause), those the heading explains, by cause key."""
    return {k: v for k, v in by_cause.items() if k != UNEXPLAINED}


def heading_causes_text(heading: dict[str, int]) -> str:
    """'N before its heading was found, M within 30 s of a reset …' for counts by cause key."""
    return ", ".join(f"{v} {HEADING_CAUSE_WORDS.get(k, k)}" for k, v in heading.items())
