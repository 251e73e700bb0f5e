"""What follows from the heading monitor's check, the part alone (estimator/monitor_follow_up.py), built without a
filter: the GNSS holds the heading only while the yaw's honest 1σ (the unconfirmed heading's floor included) is below
the limit; a GNSS yaw within the gate confirms the biases, and the bank takes the filter's gyro bias only when it is
sure; a monitor floor marks a rejection and raises the yaw variance only when above it. The expected answers are the
rules written out by hand, not the part's output."""

from __future__ import annotations

import math

import pytest

from ahrsd.estimator.heading_monitor import MonitorDecision
from ahrsd.estimator.monitor_follow_up import heading_observable, monitor_follow_up

DEG = math.pi / 180.0
OBSERVABLE = 2.0 * DEG
GATE = 3.0
BANK_SIGMA = 5.0 * DEG


def _decision(floor_rad2: float = 0.0) -> MonitorDecision:
    return MonitorDecision(mag_use=True, mag_bias_var_rad2=0.0, yaw_var_floor_rad2=floor_rad2, reset_yaw_to_rad=None,
                           reset_yaw_var_rad2=0.0)


def _follow(d=None, **kw):
    args = dict(yaw_rad=0.0, yaw_var_rad2=(1.0 * DEG) ** 2, gsf_yaw_rad=1.0 * DEG, gsf_var_rad2=(2.0 * DEG) ** 2,
                gsf_valid=True, gate_sigma=GATE, lowpassed_velocity_nis=1.0, reset_velocity_nis=10.0,
                accel_bias_gsf_sigma_rad=BANK_SIGMA, filter_yaw_var_rad2=(1.0 * DEG) ** 2)
    args.update(kw)
    return monitor_follow_up(d or _decision(), **args)


def test_the_gnss_holds_the_heading_only_below_the_limit_with_the_unconfirmed_floor_counted():
    assert heading_observable((1.9 * DEG) ** 2, math.nan, OBSERVABLE)
    assert not heading_observable((2.1 * DEG) ** 2, math.nan, OBSERVABLE)
    assert not heading_observable((1.0 * DEG) ** 2, 2.5 * DEG, OBSERVABLE)   # the unconfirmed floor too wide
    assert heading_observable((1.0 * DEG) ** 2, 1.5 * DEG, OBSERVABLE)


def test_a_gnss_yaw_within_the_gate_confirms_and_the_bank_takes_the_bias_only_when_sure():
    f = _follow()
    assert f.keep_confirmed_biases and f.bank_takes_filter_bias
    # the gate: 3σ of the sum of the two variances, wrapped
    sigma = math.sqrt((1.0 * DEG) ** 2 + (2.0 * DEG) ** 2)
    assert _follow(gsf_yaw_rad=GATE * sigma * 0.99).keep_confirmed_biases
    assert not _follow(gsf_yaw_rad=GATE * sigma * 1.01).keep_confirmed_biases
    assert _follow(yaw_rad=math.pi - 0.5 * DEG, gsf_yaw_rad=-math.pi + 0.5 * DEG).keep_confirmed_biases
    assert not _follow(gsf_valid=False).keep_confirmed_biases
    assert not _follow(lowpassed_velocity_nis=10.0).keep_confirmed_biases   # the velocities disagree
    wide = _follow(gsf_var_rad2=(6.0 * DEG) ** 2)
    assert wide.keep_confirmed_biases and not wide.bank_takes_filter_bias
    assert not _follow(gsf_valid=False).bank_takes_filter_bias


def test_a_floor_marks_a_rejection_and_raises_the_yaw_variance_only_when_above_it():
    f = _follow(_decision((10.0 * DEG) ** 2))
    assert f.rejected and f.raise_yaw_var_to_rad2 == (10.0 * DEG) ** 2
    low = _follow(_decision((0.5 * DEG) ** 2))
    assert low.rejected and low.raise_yaw_var_to_rad2 is None
    none = _follow()
    assert not none.rejected and none.raise_yaw_var_to_rad2 is None
    # the variance now is what the floor is compared with, not the one the check judged
    assert _follow(_decision((2.0 * DEG) ** 2), yaw_var_rad2=(3.0 * DEG) ** 2,
                   filter_yaw_var_rad2=(1.0 * DEG) ** 2).raise_yaw_var_to_rad2 == pytest.approx((2.0 * DEG) ** 2)
