"""The VISION_POSITION_ESTIMATE yaw while a heading change is slewed in (issue 28 "σ must cover the error",
"the daemon says what it knows"): its σ covers the offset between the yaw sent and the estimator's heading, and
the operator is told when a change starts and ends (docs/daemon.md "Calibration changes", "Restarts")."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from ahrsd.core.estimate import HeadingState
from ahrsd.daemon.heading_resets import HeadingResets
from ahrsd.daemon.heading_slew import HeadingSlew
from ahrsd.daemon.messages import statustext_chunks
from ahrsd.daemon.slew_news import SlewNews

DEG = math.radians(1.0)


def _est(t_s, heading_deg, sigma_deg=0.5):
    return SimpleNamespace(t_s=t_s, heading_true_rad=math.radians(heading_deg), rate_body_rad_s=np.zeros(3),
                           roll_rad=0.0, pitch_rad=0.0, sigma_rpy_rad=np.radians([0.2, 0.2, sigma_deg]),
                           heading_state=HeadingState.MAGNETOMETER)


def test_the_sigma_sent_covers_the_offset_left_at_3_sigma_and_no_more():
    """Worked numbers: 30° left at σ = 0.5° → σ sent = 0.5° + 10° (3σ = 31.5° = 30° + 1.5°); nothing left → σ."""
    slew = HeadingSlew(max_rate_deg_s=3.0)
    slew.update(0.0, 0.0)
    slew.start_transition()
    slew.update(0.01, math.radians(30.0))         # the estimator's heading moved 30°; the published hardly
    left_deg = math.degrees(slew.remaining_rad)
    assert 29.9 < left_deg <= 30.0
    assert abs(math.degrees(slew.published_sigma_rad(0.5 * DEG)) - (0.5 + left_deg / 3.0)) < 1e-9
    for k in range(2, 2000):                       # 20 s at 100 Hz: done (3 °/s, at least 10 s)
        slew.update(0.01 * k, math.radians(30.0))
    assert not slew.active and slew.remaining_rad == 0.0
    assert slew.published_sigma_rad(0.5 * DEG) == 0.5 * DEG


def test_the_vpe_carries_that_sigma_and_the_estimators_outside_a_slew():
    resets = HeadingResets(HeadingSlew(max_rate_deg_s=3.0))
    yaw, counter, sigma = resets.autopilot_yaw(_est(0.0, 10.0))
    assert math.isclose(math.degrees(sigma), 0.5)
    resets.slew.start_transition()
    resets.autopilot_yaw(_est(0.033, 10.0))
    yaw, _c, sigma = resets.autopilot_yaw(_est(0.066, 40.0))
    err_deg = 40.0 - math.degrees(yaw)             # the estimator's heading is the truth here
    assert err_deg > 29.0
    assert 3.0 * math.degrees(sigma) >= err_deg + 3.0 * 0.5 - 1e-9   # covers the offset and the estimator's 3σ


def test_a_slew_is_announced_when_it_starts_and_ends_in_one_statustext_each():
    texts = []
    resets = HeadingResets(HeadingSlew(max_rate_deg_s=3.0), statustext=lambda sev, text: texts.append(text))
    resets.autopilot_yaw(_est(0.0, 0.0))
    resets.slew.start_transition()
    t = 0.0
    for k in range(1, 30 * 25):                    # 25 s of VPEs at 30 Hz, the heading 30° away
        t = k / 30.0
        resets.autopilot_yaw(_est(t, 30.0))
        if k == 30:
            assert resets.status_text().startswith("slew +")        # the status line says what is left
    # the largest offset: 30° less the first 1/30 s at 3 °/s
    assert texts == ["ahrsd: calibration changed, slewing ≤3°/s", "ahrsd: yaw change 29.9° slewed in"]
    assert resets.status_text() == ""
    assert all(len(statustext_chunks(6, x, 1)) == 1 for x in texts)


def test_a_transition_that_moves_nothing_says_nothing_and_a_reset_ending_one_says_so():
    texts = []
    news = SlewNews(lambda sev, text: texts.append(text))
    slew = HeadingSlew(max_rate_deg_s=2.0)
    slew.update(0.0, 0.0)
    slew.start_transition()                        # a gyro calibration: the heading does not move
    for k in range(1, 1200):
        slew.update(k / 100.0, 0.0)
        news.after_update(slew)
    assert not slew.active and texts == []
    slew.start_from(math.radians(100.0), hold_until_s=math.inf, reason="restart hdg -100°")
    slew.update(12.0, 0.0)
    news.after_update(slew)
    slew.stop("sent as a yaw reset")
    slew.update(12.1, 0.0)
    news.after_update(slew)
    assert texts == ["ahrsd: restart hdg -100°, yaw held to realign", "ahrsd: yaw change 100.0° sent as a yaw reset"]
    assert all(len(statustext_chunks(6, x, 1)) == 1 for x in texts)
    # the longest a start can be: a restart of -180° slewed at a fractional rate
    slew = HeadingSlew(max_rate_deg_s=2.5)
    slew.update(20.0, 0.0)
    slew.start_from(math.radians(180.0), reason="restart hdg -180°")
    slew.update(20.1, 0.0)
    news.after_update(slew)
    assert texts[-1] == "ahrsd: restart hdg -180°, slewing ≤2.5°/s" and len(statustext_chunks(6, texts[-1], 1)) == 1


def test_the_slew_is_held_to_2_degrees_per_second_while_the_sigma_it_needs_is_above_ekf3s_5_degree_floor():
    """Worked numbers: σ 0.5°, a 30° change at 3 °/s: 2 °/s while 0.5° + offset/3 > 5° (offset > 13.5°), then
    3 °/s: (30 − 13.5)/2 + 13.5/3 = 12.75 s (at a constant 3 °/s, 10 s)."""
    slew = HeadingSlew(max_rate_deg_s=3.0, min_duration_s=0.0)
    slew.start_from(0.0)
    t, steps = 0.0, []
    while slew.active and t < 60.0:
        t += 0.01
        before = slew.remaining_rad
        slew.update(t, math.radians(30.0), 0.0, 0.5 * DEG)
        steps.append((math.degrees(before), math.degrees(before - slew.remaining_rad) / 0.01))
    assert abs(t - 12.75) < 0.05
    assert all(abs(rate - 2.0) < 1e-6 for left, rate in steps[1:] if left > 13.6)
    assert all(abs(rate - 3.0) < 1e-6 for left, rate in steps[1:] if 0.1 < left < 13.4)


def test_a_large_change_slewed_with_its_honest_sigma_is_fused_by_the_fake_autopilots():
    """What the daemon sends for a 90° change at 3 °/s (HeadingSlew and its σ), fed to the fake autopilots that
    have fused our heading for 2 min with no gap before the change (a calibration change): none rejects a VPE,
    and each ends within 1° of the new heading. The σ that covers the offset makes EKF3's R large and its yaw
    follow slowly; at a constant 3 °/s EKF3 is left beyond its gate when the offset shrinks (bench/slew_variance.py)."""
    from support.fake_autopilot_yaw import FakeEkf2, FakeEkf3, warm_up

    sigma = 0.5 * DEG
    fakes = {"EKF3 0.05": FakeEkf3(0.05), "EKF3 0.05 4.6 angErr": FakeEkf3(0.05, ang_err_rule="cbrt"),
             "EKF3 0.2": FakeEkf3(0.2), "EKF2 0.05": FakeEkf2(0.05)}
    for ap in fakes.values():
        warm_up(ap, 0.0, 120.0, -120.0, angle_vars=(sigma * sigma,) * 3)
    slew = HeadingSlew(max_rate_deg_s=3.0)
    slew.update(-1.0 / 30.0, 0.0)
    slew.start_transition(reason="test")
    for k in range(int(150 * 30)):                 # the slew, then the new heading held
        t = k / 30.0
        yaw = slew.update(t, 90.0 * DEG, 0.0, sigma)
        var = slew.published_sigma_rad(sigma) ** 2
        for ap in fakes.values():
            ap.feed(t, yaw, 0, (sigma * sigma, sigma * sigma, var))
    for name, ap in fakes.items():
        assert ap.rejected == 0, name
        assert abs(math.degrees(math.remainder(ap.yaw - 90.0 * DEG, 2 * math.pi))) < 1.0, name


def _heading_deg(k):
    """The estimator's heading at the k-th VPE after the change: 40°, still settling by 10° over the first 1 s."""
    return 40.0 + 10.0 * min(k / 30.0, 1.0)


def _first_vpes_after_a_change(sent_before_s):
    """VPEs at 30 Hz from t = 1000 s after a calibration change, the estimator's heading `_heading_deg`; the
    last VPE before it at 0° `sent_before_s` earlier (None: none ever sent, the heading was unknown). Returns the
    yaws sent (deg), the texts and the slew."""
    texts = []
    resets = HeadingResets(HeadingSlew(max_rate_deg_s=2.0), statustext=lambda sev, text: texts.append(text))
    if sent_before_s is not None:
        resets.autopilot_yaw(_est(1000.0 - sent_before_s, 0.0))
    resets.withheld(_est(999.9, 40.0))            # the heading unknown meanwhile: nothing sent
    resets.slew.start_transition()
    yaws = [math.degrees(resets.autopilot_yaw(_est(1000.0 + k / 30.0, _heading_deg(k)))[0]) for k in range(30 * 30)]
    return np.array(yaws), texts, resets.slew


def test_with_no_heading_ever_sent_the_first_vpe_is_the_estimators_heading_without_a_slew():
    """A first calibration of a vehicle whose heading was unknown (tour: `st2`, `ahrsd magcal start`, accept):
    the autopilot never had a heading of ours, so there is nothing to slew from and nothing to announce."""
    expected = [_heading_deg(k) for k in range(30 * 30)]
    yaws, texts, slew = _first_vpes_after_a_change(None)
    assert np.allclose(yaws, expected) and texts == [] and not slew.active
    assert slew.ended_why == "nothing sent before"
    # the same after a heading last sent longer ago than the autopilot keeps it (as a restart's memory)
    yaws, texts, slew = _first_vpes_after_a_change(601.0)
    assert np.allclose(yaws, expected) and texts == [] and not slew.active


def test_a_heading_sent_before_the_gap_is_still_slewed_from():
    yaws, texts, slew = _first_vpes_after_a_change(60.0)
    assert yaws[0] < 1.0 and abs(yaws[-1] - 50.0) < 0.1        # from where the autopilot was, to the new one
    assert np.all(np.diff(yaws) <= 2.0 / 30.0 + 1e-9)          # at ≤ 2 °/s
    assert texts[0] == "ahrsd: calibration changed, slewing ≤2°/s" and texts[1].endswith("° slewed in")
