"""The GNSS fix intake alone (estimator/gnss_intake.py, GnssFixIntake), built without a filter: which fixes are
taken, queued or refused, what of a fix is usable and how much each part is trusted, and what is counted. The
expected values are the rules written out by hand (the receiver's 1σ or the default, never below the floor)."""

from __future__ import annotations

import math

import numpy as np

from ahrsd.core.gnss import DEFAULT_H_ACC_M, DEFAULT_S_ACC_M_S, GnssFix, GnssFixType
from ahrsd.estimator.gnss_intake import GnssFixIntake


def _intake(max_queued: int = 3):
    rejected = []
    intake = GnssFixIntake(max_queued=max_queued, use_vertical_velocity=True, min_h_acc_m=0.5, min_v_acc_m=0.8,
                           min_s_acc_m_s=0.1, reject_reset_s=5.0, on_reject=lambda: rejected.append(1))
    return intake, rejected


def _fix(t_s: float, **kw) -> GnssFix:
    return GnssFix(t_s, kw.pop("lat", 47.0), kw.pop("lon", 8.0), kw.pop("alt", 400.0),
                   np.asarray(kw.pop("vel", (1.0, 2.0, 0.1)), dtype=float), **kw)


def test_a_fix_ahead_of_the_samples_waits_until_they_reach_it():
    intake, rejected = _intake()
    assert intake.offer(_fix(1.0), True, 1.0)            # its time reached: fused now
    assert not intake.offer(_fix(1.2), True, 1.1)        # ahead: queued
    assert intake.pop_due(1.15) is None
    assert intake.pop_due(1.2).t_s == 1.2
    assert intake.pop_due(1.3) is None
    c = intake.counters
    assert (c.offered, c.queued, c.invalid) == (2, 1, 0) and not rejected


def test_a_fix_not_after_the_previous_one_or_too_far_ahead_is_refused_and_flagged():
    intake, rejected = _intake(max_queued=1)
    assert intake.offer(_fix(2.0), True, 2.0)
    assert not intake.offer(_fix(2.0), True, 2.0)        # not after the previous fix
    assert not intake.offer(_fix(1.0), True, 2.0)
    assert not intake.offer(_fix(3.0), True, 2.0)        # queued (one place)
    assert not intake.offer(_fix(3.5), True, 2.0)        # no place left
    c = intake.counters
    assert (c.time_backwards, c.queued, c.invalid) == (2, 1, 1)
    assert len(rejected) == 3


def test_before_the_filter_starts_a_fix_is_counted_not_flagged():
    intake, rejected = _intake()
    assert not intake.offer(_fix(1.0), False, 1.0)
    assert intake.counters.before_init == 1 and not rejected
    assert intake.offer(_fix(1.0), True, 1.0)            # its time is not taken: the same fix once started


def test_a_reset_forgets_the_queue_and_the_last_time_but_not_the_counts():
    intake, _ = _intake()
    intake.offer(_fix(5.0), True, 4.0)
    intake.reset()
    assert intake.pop_due(10.0) is None
    assert intake.offer(_fix(1.0), True, 1.0)
    assert intake.counters.offered == 2


def test_the_usable_parts_and_their_sigma():
    intake, rejected = _intake()
    parts = intake.read(_fix(1.0, h_acc_m=0.2, v_acc_m=3.0, s_acc_m_s=math.nan))
    assert (parts.use_pos, parts.use_alt, parts.use_vel, parts.use_vd) == (True, True, True, True)
    assert parts.sigma_h_m == 0.5                      # the receiver's 0.2 m, raised to the floor
    assert parts.sigma_v_m == 3.0                      # the receiver's
    assert parts.sigma_s_m_s == DEFAULT_S_ACC_M_S      # none given
    parts = intake.read(_fix(1.0, fix_type=GnssFixType.FIX_2D, vel=(math.nan, 0.0, 0.0), h_acc_m=-1.0))
    assert (parts.use_pos, parts.use_alt, parts.use_vel, parts.use_vd) == (True, False, False, False)
    assert parts.sigma_h_m == DEFAULT_H_ACC_M
    assert not rejected


def test_a_fix_with_nothing_usable_is_counted_invalid_and_flagged():
    intake, rejected = _intake()
    assert intake.read(_fix(1.0, fix_type=GnssFixType.NO_FIX)) is None
    assert intake.read(_fix(1.0, lat=math.nan, vel=(math.nan, math.nan, 0.0))) is None
    assert intake.read(_fix(1.0, vel=(1.0, 2.0))) is None          # malformed: two components
    assert intake.counters.invalid == 3 and len(rejected) == 3
