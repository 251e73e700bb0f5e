"""The heading monitor raises σ before anything moves (issue 28): at the check that rejects the magnetometer, the
yaw variance floor covers what the magnetometer may already have pulled the heading by (its low-passed innovation)
and the disagreement with a valid GNSS yaw; `ins` applies that floor to its covariance. Worked numbers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ahrsd.estimator.heading_monitor import HeadingMonitor

D = math.radians


def _checks(monitor, mag_yaws_deg, gsf=(math.nan, math.inf, False), yaw_sigma_deg=0.3, mag_sigma_deg=0.5):
    out = []
    for i, m in enumerate(mag_yaws_deg):
        out.append(monitor.check(0.2 * i, 0.0, D(yaw_sigma_deg) ** 2, D(m), D(mag_sigma_deg) ** 2,
                                 gsf[0], gsf[1], gsf[2], True))
    return out


def test_the_rejecting_check_raises_the_floor_to_the_lowpassed_innovation():
    """10 consistent checks, then the magnetometer says 8° (an iron step): nothing happens at the first two
    failing checks; the third rejects it with floor = lp² + σ_yaw², lp = 8° (1 − (1 − k)³), k = 1 − e^(−0.2/5)."""
    mon = HeadingMonitor(D(0.5))
    d = _checks(mon, [0.0] * 10 + [8.0] * 3)
    assert all(x.yaw_var_floor_rad2 == 0.0 and x.mag_use for x in d[:12])
    k = 1.0 - math.exp(-0.2 / 5.0)
    lp = D(8.0) * (1.0 - (1.0 - k) ** 3)
    assert not d[12].mag_use
    assert d[12].yaw_var_floor_rad2 == pytest.approx(lp ** 2 + D(0.3) ** 2, rel=1e-9)


def test_with_a_valid_gnss_yaw_the_floor_covers_the_disagreement_with_it():
    """The same, with a valid GNSS yaw 6° ± 1° from the filter's: floor = max(lp² + σ², 6² + 1² deg²)."""
    mon = HeadingMonitor(D(0.5))
    d = _checks(mon, [0.0] * 10 + [8.0] * 3, gsf=(D(6.0), D(1.0) ** 2, True))
    rejecting = [x for x in d if x.yaw_var_floor_rad2 > 0.0]
    assert len(rejecting) == 1 and not rejecting[0].mag_use
    assert rejecting[0].yaw_var_floor_rad2 == pytest.approx(D(6.0) ** 2 + D(1.0) ** 2, rel=1e-9)


def test_ins_applies_the_floor_before_the_next_step():
    """On the simulated boat whose hard iron moves by 9 µT: every floor the monitor decides is in ins's yaw
    variance when the check returns (before the next sample or fix can move the estimate), as its record of each
    check (`Ins.heading_checks`) shows. (Broken by dropping the floor's `P[yaw, yaw] = floor`: fails.)"""
    from ahrsd.core.sample import SampleFlags, make_sample
    from ahrsd.estimator.ins import Ins
    from bench.vehicle_accuracy import simulate_vehicle

    run = simulate_vehicle("boat", 140.0, 3, None, mag="iron-step")
    est = Ins(declination_rad=run.declination_rad, mag_calibration_sigma_rad=run.mag_calibration_sigma_rad)
    checks = []
    fi = 0
    for k in range(len(run.t_s)):
        while fi < len(run.fixes) and run.fixes[fi].extra["t_rx_s"] <= run.t_s[k]:
            est.update_gnss(run.fixes[fi])
            fi += 1
            checks += [c for c in est.heading_checks if not checks or c.t_s > checks[-1].t_s]
        # step, not update: the checks are read, no estimate (building none changes none: estimate_view.py)
        est.step(make_sample(run.t_s[k], run.gyro_rad_s[k], run.accel_m_s2[k], run.mag_ut[k],
                             flags=SampleFlags.NEW_DATA))
    assert len(checks) > 500                    # a check at (nearly) every fix of 140 s at 5 Hz
    applied = [(c.yaw_var_floor_rad2, c.yaw_var_rad2) for c in checks if c.yaw_var_floor_rad2 > 0.0]
    assert applied, "the iron step was never rejected"
    assert all(p >= f for f, p in applied), applied
    assert np.sqrt(max(f for f, _ in applied)) > 3.0 * D(0.3)
    assert not any(c.mag_use for c in checks if c.yaw_var_floor_rad2 > 0.0)   # a floor comes with the rejection


def test_reentry_counts_consistency_only_while_the_gnss_holds_the_heading():
    """After an iron step the magnetometer is rejected and the yaw σ raised past what the GNSS holds (2°): for
    30 s its learned correction agrees with a filter heading that is itself unknown, which shows nothing. It
    re-enters after `reentry_s` = 20 s of agreement once the heading is observable again (at 50 s), not at the
    first observable check (30 s) after 30 s of checks against an unheld heading."""
    mon = HeadingMonitor(D(0.5))
    _checks(mon, [0.0] * 10 + [8.0] * 3)
    assert mon.mag_rejected
    t0 = 0.2 * 13
    uses = []
    for i in range(300):                       # 60 s of checks at 5 Hz, the magnetometer agreeing with the filter
        t = t0 + 0.2 * i
        d = mon.check(t, 0.0, D(0.3) ** 2, 0.0, D(2.0) ** 2, math.nan, math.inf, False,
                      heading_observable=t >= t0 + 30.0 - 1e-9, mag_bias_var_rad2=D(2.0) ** 2)
        uses.append((t - t0, d.mag_use))
    back = [t for t, use in uses if use]
    assert back, "the magnetometer never re-entered"
    assert back[0] == pytest.approx(30.0 + 20.0, abs=0.21), back[0]


def test_a_magnetometer_whose_heading_error_is_not_trusted_never_re_enters_however_long_it_agrees():
    """Agreement is not enough: the magnetometer heading's slowly varying error (its calibration and learned iron,
    `mag_bias_var`) must be below `trusted_sigma_rad` (3°) too. 60 s of agreement while the GNSS holds the heading
    with that error at 5°: still rejected; the first check with it at 2°: back at once (the agreement has held)."""
    mon = HeadingMonitor(D(0.5))
    _checks(mon, [0.0] * 10 + [8.0] * 3)
    assert mon.mag_rejected
    t0 = 0.2 * 13
    for i in range(300):
        d = mon.check(t0 + 0.2 * i, 0.0, D(0.3) ** 2, 0.0, D(5.0) ** 2, math.nan, math.inf, False,
                      heading_observable=True, mag_bias_var_rad2=D(5.0) ** 2)
        assert not d.mag_use, f"re-entered at {0.2 * i:.1f} s with a 5° heading error"
    d = mon.check(t0 + 60.0, 0.0, D(0.3) ** 2, 0.0, D(2.0) ** 2, math.nan, math.inf, False,
                  heading_observable=True, mag_bias_var_rad2=D(2.0) ** 2)
    assert d.mag_use and not mon.mag_rejected


def test_a_reset_check_decides_no_learning():
    """A check that resets the yaw to the GNSS yaw (valid, 40° ± 2° off a filter yaw of σ 0.3°, the magnetometer
    rejected, the filter's velocity fusion failing) says nothing is learned at it: the heading σ the learning was
    judged on is the one from before the reset. The next check, the yaw now where the reset put it and agreeing,
    learns again. The same for a reset made by the caller (`yaw_was_reset`, the GNSS-yaw alignment)."""
    mon = HeadingMonitor(D(0.5))
    _checks(mon, [0.0] * 10 + [20.0] * 3)
    assert mon.mag_rejected
    mon.lowpassed_velocity_nis = 50.0
    d = mon.check(3.0, 0.0, D(0.3) ** 2, D(20.0), D(0.5) ** 2, D(40.0), D(2.0) ** 2, True, True, 50.0)
    assert d.reset_yaw_to_rad == pytest.approx(D(40.0))
    assert not mon.learning
    d = mon.check(3.2, D(40.0), D(0.3) ** 2, D(20.0), D(0.5) ** 2, D(40.0), D(2.0) ** 2, True, True, 50.0)
    assert d.reset_yaw_to_rad is None and mon.learning
    mon.yaw_was_reset(3.2)
    assert not mon.learning and mon.last_reset_t_s == 3.2


def test_ins_learns_no_iron_on_a_check_that_resets_the_yaw():
    """The held-out car without calibration, its magnetometer rejected and its iron being learned (26–57 s): at
    40 s its yaw is turned 30° away without its covariance knowing (injected into the state). The car then drives
    without turning, so nothing shows it until ~50 s, when the GNSS velocity fails and the yaw is reset to the
    GNSS yaw. The iron learner must not update at that check: its attitude would be the one from before the reset
    (30° off) and its covariance the one after it. It learns again at the following checks. Broken (the iron
    update on every learning check, as before): one update at the reset check."""
    from ahrsd.core.sample import SampleFlags, make_sample
    from ahrsd.estimator import ins_core as core
    from ahrsd.estimator.ins import Ins
    from bench.vehicle_accuracy import HONESTY_SITES, simulate_vehicle

    site, iron = HONESTY_SITES["held-out"]
    run = simulate_vehicle("car", 52.0, 14, site, mag="uncalibrated", iron=iron)
    est = Ins(declination_rad=run.declination_rad, lever_arm_m=run.lever_arm_m,
              mag_calibration_sigma_rad=run.mag_calibration_sigma_rad)
    turned = False
    reset_checks, learned_after = [], 0
    fi = 0
    for k, t in enumerate(run.t_s):
        if not turned and t >= 40.0:
            assert est._heading.monitor.mag_rejected and est._heading.monitor.learning, "the scenario: learning when turned"
            core._rotate_attitude(est._x["q"], 0.0, 0.0, D(30.0))
            turned = True
        while fi < len(run.fixes) and run.fixes[fi].extra["t_rx_s"] <= t:
            resets, updates, offset = est.yaw_resets, est._iron.updates, est._iron.offset_ut
            est.update_gnss(run.fixes[fi])
            fi += 1
            if turned and est.yaw_resets > resets:
                reset_checks.append((t, est._iron.updates - updates, float(np.abs(est._iron.offset_ut - offset).max())))
            elif reset_checks:
                learned_after += est._iron.updates - updates
        est.update(make_sample(t, run.gyro_rad_s[k], run.accel_m_s2[k], run.mag_ut[k], flags=SampleFlags.NEW_DATA))
    assert reset_checks, "the turned yaw was never reset"
    assert all(n == 0 and moved == 0.0 for _, n, moved in reset_checks), reset_checks
    assert learned_after > 0
