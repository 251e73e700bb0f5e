"""The one slew (estimator/slewed_yaw.YawSlew) that ins's published heading and the daemon's heading slew build on:
its step and σ against numbers worked by hand, and both users taking that step."""

from __future__ import annotations

import math

import pytest

from ahrsd.daemon.heading_slew import HeadingSlew
from ahrsd.estimator.published_heading import PublishedHeading
from ahrsd.estimator.slewed_yaw import YawSlew

D = math.radians


@pytest.mark.parametrize("rate_deg_s, offset_deg, dt_s, move_deg, arrived", [
    (2.0, 6.0, 0.5, -1.0, False),       # σ sent 0.5 + 6/3 = 2.5° ≤ 5°: the configured 2 °/s, 1° in 0.5 s
    (2.0, -6.0, 0.5, 1.0, False),       # towards the estimator's yaw, whichever side
    (10.0, 30.0, 0.5, -1.0, False),     # σ sent 0.5 + 10 = 10.5° > 5°: held to 2 °/s
    (10.0, 12.0, 0.5, -5.0, False),     # σ sent 0.5 + 4 = 4.5° ≤ 5°: 10 °/s
    (2.0, 0.8, 0.5, -0.8, True),        # within one step (1°): all of it
])
def test_a_step_moves_by_the_rate_held_to_2_deg_s_while_the_sigma_sent_is_above_5_deg(rate_deg_s, offset_deg, dt_s,
                                                                                       move_deg, arrived):
    move, got_arrived = YawSlew(D(rate_deg_s)).step(D(offset_deg), D(0.5), dt_s)
    assert math.degrees(move) == pytest.approx(move_deg, abs=1e-12)
    assert got_arrived is arrived


def test_within_the_arrival_tolerance_it_arrives_without_time_and_its_sigma_covers_the_offset():
    slew = YawSlew(D(2.0), arrive_within_rad=D(0.05))
    assert slew.step(D(0.04), 0.0, 0.0) == (pytest.approx(D(-0.04), abs=1e-15), True)
    assert slew.step(D(0.06), 0.0, 0.0)[1] is False
    assert math.degrees(slew.sigma_rad(D(0.5), D(-30.0))) == pytest.approx(10.5)      # 0.5 + 30/3


def test_ins_and_the_daemon_take_the_same_capped_step_from_a_30_degree_offset():
    """30° to slew at a configured 10 °/s with σ 0.5°: σ sent 10.5° > 5°, so both move 0.5° in 0.25 s (2 °/s)."""
    published = PublishedHeading(D(10.0))
    published.update(0.0, 0.0, 0.0, 0.0, (0.0, 0.0, 0.0), D(0.5))
    published.update(0.25, D(-30.0), 0.0, 0.0, (0.0, 0.0, 0.0), D(0.5))    # the filter's yaw reset by −30°
    assert math.degrees(published.offset_rad) == pytest.approx(29.5, abs=1e-9)

    daemon = HeadingSlew(max_rate_deg_s=10.0)
    daemon.update(0.0, D(100.0), 0.0, D(0.5))                               # what the autopilot has
    daemon.start_transition()
    sent = daemon.update(0.25, D(130.0), 0.0, D(0.5))                       # a calibration moved it by +30°
    assert math.degrees(sent) == pytest.approx(100.5, abs=1e-9)
    assert math.degrees(daemon.remaining_rad) == pytest.approx(29.5, abs=1e-9)
