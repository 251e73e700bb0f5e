"""What the GNSS velocities the aided levelling's filter rejected say (backstepping_aided.py, `calibrate mag --gnss`):
counted by their cause as each sample's estimate goes by (estimator/velocity_rejection_watch.py), and the
warning that names the cause the evidence supports (`rejection_warning`). The rule is the daemon's
(estimator/velocity_rejection_cause.py): the heading when the rejections came while the filter's heading was not one to trust — before it was found, just after
a reset to the GNSS yaw, while the magnetometer disagreed or its iron stepped — and the antenna's lever arm and the
fixes' time stamps only when the heading cannot explain them. A levelling without a magnetometer heading (the one
`calibrate mag --gnss` falls back to when the accelerometer-levelled fit is refused) takes its yaw from the GNSS
velocity in accelerations and rejects correct fixes until it has it (docs/gnss.md "Offline")."""

from __future__ import annotations

from ahrsd.estimator.velocity_rejection_watch import heading_causes_text, heading_explained

MAX_REJECTED_VELOCITY_FRACTION = 0.01   # of the offered fixes: more, and the filter did not converge


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
    heading = heading_explained(by_cause)
    unexplained = g["rejected_velocity"] - sum(heading.values())
    if heading and unexplained <= MAX_REJECTED_VELOCITY_FRACTION * max(g["offered"], 1):
        causes = heading_causes_text(heading)
        return (f"{text}, while its heading was not yet one to trust ({causes}): a filter rejects correct fixes "
                "until it has its heading (from the magnetometer, or from the GNSS velocity in accelerations), "
                "not for the antenna's lever arm or the fixes' time stamps")
    arm = tuple(float(v) for v in (filter_overrides or {}).get("lever_arm_m", (0.0, 0.0, 0.0)))
    known = f" ({unexplained} of them with its heading known)" if heading else ""
    return (f"{text}{known}: check the antenna's lever arm (the levelling was told "
            f"{' '.join(f'{v:g}' for v in arm)} m, body FRD from the IMU) and the fixes' time stamps")
