"""The latest heading checks' records (`Ins.heading_checks`): what each check at a fused fix decided and left.

A reader — a test, a diagnosis, tools/estimate_digest.py — sees each decision (the magnetometer used or not, the
monitor's yaw variance floor, the filter's yaw variance when the check returned, a reset's yaw, whether the iron
learner updated, the step test's step) without reaching into the check. Only the latest `HEADING_CHECKS_KEPT` are
kept: the daemon runs for days, one check per fused fix. The log is told its inputs by the check (Ins._check_heading)
and reads nothing of the filter.
"""

from __future__ import annotations

from collections import deque

from .heading_monitor import HeadingCheckRecord, MonitorDecision

HEADING_CHECKS_KEPT = 128   # the latest heading checks a reader can look at (`Ins.heading_checks`)


class HeadingCheckLog:
    """The latest heading checks' records, oldest first (`records`, a deque of HeadingCheckRecord)."""

    def __init__(self, kept: int = HEADING_CHECKS_KEPT) -> None:
        self.records: deque[HeadingCheckRecord] = deque(maxlen=kept)

    def add(self, t_s: float, decision: MonitorDecision, yaw_var_rad2: float, reset_yaw_to_rad: float | None,
            iron_learned: bool) -> HeadingCheckRecord:
        """One check's record: the monitor's decision at t_s, the filter's yaw variance when the check returned
        (after any floor or reset, rad²), the yaw a reset or the alignment turned the attitude to (None: none), and
        whether the iron learner updated at this check. The oldest record goes when the log is full."""
        record = HeadingCheckRecord(t_s, decision.mag_use, decision.yaw_var_floor_rad2, yaw_var_rad2,
                                    reset_yaw_to_rad, iron_learned, decision.mag_step_rad)
        self.records.append(record)
        return record
