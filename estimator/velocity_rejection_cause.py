"""Why an aided filter rejects GNSS velocities: its heading, or the antenna's place and the fixes' time stamps. The one
rule of the daemon's warning (daemon/heading_status.py `rejection_cause`, said by daemon/gnss_task.py) and of the
offline levelling's (calibration/mag/backstepping_aided.py, `calibrate mag --gnss`).

The filter predicts the velocity by integrating the accelerometer's specific force turned to NED through its
attitude. With the attitude right it rejects a correct fix only when the fix does not fit the IMU's motion: an
antenna that is not where the filter was told (it moves as the vehicle rolls and turns), or a fix whose time stamp
is off. With the heading wrong, or not known yet, every acceleration is turned the wrong way and correct fixes are
rejected until the heading is found (Groves, Principles of GNSS, Inertial, and Multisensor Integrated Navigation
Systems, 2nd ed., §14.2.1: the heading is observed through the GNSS velocity only in accelerations). So the
heading is named when, at the rejections, the heading was not one the filter could trust:

- the magnetometer was rejected for a step of its heading the gyro did not see (an iron that changed: the gyro and
  the magnetometer say so without the GNSS);

and, unless the lever-arm check (lever_arm_fit.py) finds that a wrong antenna arm explains the velocity innovations
— a wrong arm also turns the GNSS yaw bank's yaw (it takes the same velocities through the same arm), so a
magnetometer disagreeing with it, and a heading not yet found or just reset, then say nothing of the cause —

- the magnetometer disagreed with the GNSS(-held) heading;
- the yaw was reset (or first aligned) to the GNSS yaw within YAW_RESET_CAUSE_S: the filter's velocity and
  accelerometer-bias states still carry the wrong heading's integration;
- the heading was unknown (none published yet: a filter without a magnetometer heading before the GNSS yaw was
  found).

The lever arm and the time stamps are named when none of these held, or when the lever-arm check explains the
rejections and the iron did not step.
"""

from __future__ import annotations

import math
from typing import NamedTuple

YAW_RESET_CAUSE_S = 30.0     # a yaw reset this recent explains rejected GNSS velocities


class HeadingCause(NamedTuple):
    """The heading as the cause of rejected GNSS velocities: `key` (one of KEYS: stable, for counting) and
    `text`, a short phrase that fits a STATUSTEXT ("mag vs GNSS 36°")."""

    key: str
    text: str


KEYS = ("iron step", "mag disagrees", "heading reset", "heading unknown")


def heading_rejection_cause(*, iron_step_rad: float = math.nan, mag_inconsistent: bool = False,
                            disagreement_rad: float = math.nan, since_yaw_reset_s: float = math.inf,
                            heading_unknown: bool = False, lever_arm_explains: bool = False) -> HeadingCause | None:
    """The heading as the cause of rejected GNSS velocities, or None when the heading cannot explain them (then the
    lever arm or the time stamps). `iron_step_rad`: the magnetometer is rejected for this step of its heading
    (NaN: not); `mag_inconsistent`: it disagrees with the GNSS(-held) heading, by `disagreement_rad` (NaN: no
    valid GNSS yaw to say by how much); `since_yaw_reset_s`: since the yaw was last reset to the GNSS yaw (inf:
    never); `heading_unknown`: no heading known yet; `lever_arm_explains`: the lever-arm check (lever_arm_fit.py)
    finds the told antenna arm wrong by enough to explain the innovations."""
    if math.isfinite(iron_step_rad):
        return HeadingCause("iron step", f"mag iron step {math.degrees(iron_step_rad):+.0f}°")
    if lever_arm_explains:
        return None
    if mag_inconsistent:
        return HeadingCause("mag disagrees", f"mag vs GNSS {abs(math.degrees(disagreement_rad)):.0f}°"
                            if math.isfinite(disagreement_rad) else "mag rejected")
    if since_yaw_reset_s <= YAW_RESET_CAUSE_S:
        return HeadingCause("heading reset", "heading reset")
    if heading_unknown:
        return HeadingCause("heading unknown", "heading unknown")
    return None
