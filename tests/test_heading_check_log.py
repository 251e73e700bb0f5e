"""The heading checks' records, the part alone (estimator/heading_check_log.py), built without a filter: each record
holds what its check was told, field by field (the expected values are the inputs, written out by hand), only the
latest `HEADING_CHECKS_KEPT` are kept, oldest dropped first; and the filter's `heading_checks` is a fresh log after
`reset()`."""

from __future__ import annotations

import math

from ahrsd.estimator.heading_check_log import HEADING_CHECKS_KEPT, HeadingCheckLog
from ahrsd.estimator.heading_monitor import HeadingCheckRecord, MonitorDecision
from ahrsd.estimator.ins import Ins


def _decision(mag_use: bool, floor: float, step: float = math.nan) -> MonitorDecision:
    return MonitorDecision(mag_use=mag_use, mag_bias_var_rad2=7.0, yaw_var_floor_rad2=floor, reset_yaw_to_rad=None,
                           reset_yaw_var_rad2=9.0, mag_step_rad=step)


def test_a_record_holds_what_its_check_was_told():
    log = HeadingCheckLog()
    log.add(1.5, _decision(False, 0.25, step=0.4), 0.0625, 1.2, True)
    log.add(1.7, _decision(True, 0.0), 0.01, None, False)
    first, second = log.records
    assert first == HeadingCheckRecord(t_s=1.5, mag_use=False, yaw_var_floor_rad2=0.25, yaw_var_rad2=0.0625,
                                       reset_yaw_to_rad=1.2, iron_learned=True, mag_step_rad=0.4)
    assert second.t_s == 1.7 and second.mag_use and second.yaw_var_floor_rad2 == 0.0
    assert second.yaw_var_rad2 == 0.01 and second.reset_yaw_to_rad is None and not second.iron_learned
    assert math.isnan(second.mag_step_rad)


def test_only_the_latest_checks_are_kept_oldest_dropped_first():
    assert HEADING_CHECKS_KEPT == 128
    log = HeadingCheckLog()
    for k in range(HEADING_CHECKS_KEPT + 5):
        log.add(0.2 * k, _decision(True, 0.0), 0.01, None, False)
    assert len(log.records) == HEADING_CHECKS_KEPT
    assert log.records[0].t_s == 0.2 * 5 and log.records[-1].t_s == 0.2 * (HEADING_CHECKS_KEPT + 4)


def test_the_filter_reads_its_log_and_a_reset_starts_a_new_one():
    est = Ins()
    est._heading.check_log.add(3.0, _decision(True, 0.0), 0.01, None, False)
    assert [r.t_s for r in est.heading_checks] == [3.0]
    est.reset()
    assert len(est.heading_checks) == 0
