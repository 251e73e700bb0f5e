"""What follows from the heading monitor's check before any yaw reset (ins.Ins._monitor_decision applies it).

Before the check: whether the GNSS holds the heading (`heading_observable`). After it: whether a GNSS yaw agreeing
with the heading confirms the biases (a reset goes back to them) and whether the GNSS yaw bank takes the filter's
gyro bias from now on; whether the magnetometer was just rejected; and the yaw variance floor to apply. It keeps no
state and reads nothing of the filter: its inputs are arguments, and Ins writes what it answers.

Why each rule: the comments below; docs/gnss.md ("The iron learned against an unconfirmed heading") and
docs/estimator.md ("Magnetometer-free GNSS yaw", Limits; "Known limits: ins on level turns").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .heading_monitor import MonitorDecision, wrap_pi


def heading_observable(yaw_var_rad2: float, unconfirmed_sigma_rad: float, observable_sigma_rad: float) -> bool:
    """The GNSS holds the heading (the iron is learned against it, the magnetometer's agreement counts towards its
    re-entry) while the yaw's honest 1σ is below `observable_sigma_rad`: the filter's own and, until a GNSS yaw has
    confirmed the heading, the floor published for it (HeadingConfirmation.unconfirmed_yaw_sigma, NaN: none).
    The linearised pull-in shrinks the filter's variance faster than its error, and an iron learned against that yaw
    takes its error in as iron (docs/gnss.md "The iron learned against an unconfirmed heading")."""
    floor = unconfirmed_sigma_rad
    return yaw_var_rad2 < observable_sigma_rad ** 2 and not floor >= observable_sigma_rad


@dataclass(frozen=True)
class MonitorFollowUp:
    """What Ins does after the monitor's check, before any yaw reset."""

    keep_confirmed_biases: bool     # the GNSS yaw confirms the heading: its gyro bias was learned with a right one
    bank_takes_filter_bias: bool    # the bank's gyro is corrected with the filter's bias from now on
    rejected: bool                  # the magnetometer was just rejected (the monitor set a yaw variance floor)
    raise_yaw_var_to_rad2: float | None   # the filter's yaw variance raised to this (None: left)


def monitor_follow_up(d: MonitorDecision, *, yaw_rad: float, yaw_var_rad2: float, gsf_yaw_rad: float,
                      gsf_var_rad2: float, gsf_valid: bool, gate_sigma: float, lowpassed_velocity_nis: float,
                      reset_velocity_nis: float, accel_bias_gsf_sigma_rad: float,
                      filter_yaw_var_rad2: float) -> MonitorFollowUp:
    """yaw_rad, yaw_var_rad2: the filter's yaw and its variance the check judged; filter_yaw_var_rad2: the filter's
    yaw variance now (the floor raises it only if above)."""
    confirms = bool(gsf_valid and wrap_pi(gsf_yaw_rad - yaw_rad) ** 2 <= gate_sigma ** 2 * (yaw_var_rad2 + gsf_var_rad2)
                    and lowpassed_velocity_nis < reset_velocity_nis)
    # and the bank is sure enough that its agreement is not just its width: from now on the bank's gyro is corrected
    # with this bias, not the filter's. A wrong magnetometer trusted before the first check teaches the vertical gyro
    # bias its heading error's rate, and a bank that learns no bias itself would drift at that rate and hold the
    # wrong magnetometer's heading against the right one later. Tighter than the confirmed gyro bias (any agreement
    # within the gate): a bank near its validity limit agrees with headings tens of degrees off, and a bias confirmed
    # by that would drag the bank after the filter again (docs/estimator.md, "Magnetometer-free GNSS yaw", Limits)
    bank = confirms and gsf_var_rad2 < accel_bias_gsf_sigma_rad ** 2
    raise_to = d.yaw_var_floor_rad2 if d.yaw_var_floor_rad2 > filter_yaw_var_rad2 else None
    return MonitorFollowUp(confirms, bank, d.yaw_var_floor_rad2 > 0.0, raise_to)
