"""What the GNSS velocities the aided levelling's filter rejected say (backstepping_aided.py, `calibrate mag --gnss`):
counted by their cause as each sample's estimate goes by (`RejectionWatch`), and the warning that names the cause
the evidence supports (`rejection_warning`). The rule is the daemon's (estimator/velocity_rejection_cause.py): the
heading when the rejections came while the filter's heading was not one to trust — before it was found, just after
a reset to the GNSS yaw, while the magnetometer disagreed or its iron stepped — and the antenna's lever arm and the
fixes' time stamps only when the heading cannot explain them. A levelling without a magnetometer heading (the one
`calibrate mag --gnss` falls back to when the accelerometer-levelled fit is refused) takes its yaw from the GNSS
velocity in accelerations and rejects correct fixes until it has it (docs/gnss.md "Offline")."""

from __future__ import annotations

import math

from ahrsd.core.estimate import HeadingState
from ahrsd.estimator.velocity_rejection_cause import YAW_RESET_CAUSE_S, heading_rejection_cause

MAX_REJECTED_VELOCITY_FRACTION = 0.01   # of the offered fixes: more, and the filter did not converge
UNEXPLAINED = "unexplained"    # a rejected velocity the heading does not explain (RejectionWatch.by_cause)
HEADING_CAUSE_WORDS = {      # estimator/velocity_rejection_cause.py's keys, said in the levelling's warning
    "iron step": "after the magnetometer's iron stepped",
    "mag disagrees": "while the magnetometer disagreed with the GNSS yaw",
    "heading reset": f"within {YAW_RESET_CAUSE_S:g} s of a reset of its yaw to the GNSS yaw",
    "heading unknown": "before its heading was found",
}


class RejectionWatch:
    """The GNSS velocities a levelling pass's filter rejected, counted by their cause (`by_cause`): the heading's
    as estimator/velocity_rejection_cause.py names it (the daemon's rule), or UNEXPLAINED. Called with each
    sample's estimate."""

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
        cause = heading_rejection_cause(
            iron_step_rad=integrity.mag_step_rad if integrity is not None else math.nan,
            # the magnetometer this pass levels with was rejected by the filter's heading checks
            mag_inconsistent=self.mag_enabled and state in (HeadingState.GNSS_ONLY, HeadingState.LEARNING),
            disagreement_rad=(integrity.mag_disagreement_rad if integrity is not None and integrity.gsf_valid
                              else math.nan),
            since_yaw_reset_s=e.t_s - self._reset_at_s,
            # the estimator's own bound of an UNKNOWN heading, on its yaw σ: a filter levelling without a magnetometer
            # publishes no heading state of its own (UNKNOWN throughout), its yaw σ says when the GNSS found it
            heading_unknown=bool(e.sigma_rpy_rad[2] > self.est.params.heading_unknown_sigma_rad))
        key = UNEXPLAINED if cause is None else cause.key
        self.by_cause[key] = self.by_cause.get(key, 0) + new


def rejection_warning(passes: list, filter_overrides: dict | None) -> str | None:
    """When a levelling pass did not fuse the GNSS velocities cleanly: its counts and the cause the evidence
    supports (estimator/velocity_rejection_cause.py, the daemon's rule): the heading when the rejections came
    while it was not one the filter could trust (all but at most MAX_REJECTED_VELOCITY_FRACTION of the offered),
    else the antenna's lever arm and the fixes' time stamps (a filter whose heading is right fuses a correct
    fix)."""
    bad = [p for p in passes if not p.get("healthy", True)]
    if not bad:
        return None
    g = bad[-1]["gnss"]
    text = (f"the aided levelling ({bad[-1]['magnetometer']}) rejected {g['rejected_velocity']} of {g['offered']} "
            f"GNSS velocities and reset its velocity {g['reset_velocity']} times")
    by_cause = bad[-1].get("rejected_velocity_by_cause", {})
    heading = {k: v for k, v in by_cause.items() if k != UNEXPLAINED}
    unexplained = g["rejected_velocity"] - sum(heading.values())
    if heading and unexplained <= MAX_REJECTED_VELOCITY_FRACTION * max(g["offered"], 1):
        causes = ", ".join(f"{v} {HEADING_CAUSE_WORDS.get(k, k)}" for k, v in heading.items())
        return (f"{text}, while its heading was not yet one to trust ({causes}): a filter rejects correct fixes "
                "until it has its heading (from the magnetometer, or from the GNSS velocity in accelerations), "
                "not for the antenna's lever arm or the fixes' time stamps")
    arm = tuple(float(v) for v in (filter_overrides or {}).get("lever_arm_m", (0.0, 0.0, 0.0)))
    known = f" ({unexplained} of them with its heading known)" if heading else ""
    return (f"{text}{known}: check the antenna's lever arm (the levelling was told "
            f"{' '.join(f'{v:g}' for v in arm)} m, body FRD from the IMU) and the fixes' time stamps")
