"""The NED mechanisation (Groves 2nd ed. §5.4) integrates the simulator's truth back into its trajectory."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import cumulative_trapezoid
from scipy.spatial.transform import Rotation

from ahrsd.simulation import DEFAULT_SITE, open_stream
from ahrsd.core.gravity import EARTH_RADIUS_M
from ahrsd.simulation.strapdown import mechanise_ned

G_SITE = DEFAULT_SITE.gravity_m_s2


def _run(name, seconds, rate_hz, earth_rate):
    stream = open_stream(name, rate_hz=rate_hz, errors="ideal", earth_rate=earth_rate)
    b = stream.next_block(int(seconds * rate_hz) + 1)
    v_true = stream.scenario.velocity_ned_m_s(b.t_s)
    site = DEFAULT_SITE
    nav = mechanise_ned(b.t_s, b.gyro_rad_s, b.accel_m_s2, b.truth_q_wxyz[0], v_true[0], site.lat_deg,
                        site.lon_deg, site.alt_m, earth_rate=earth_rate,
                        gravity_m_s2=lambda lat, h: G_SITE)   # the simulator holds the site's g on its track
    return b, v_true, nav


def _attitude_error_rad(q1, q2):
    r1 = Rotation.from_quat(np.column_stack([q1[:, 1:], q1[:, 0]]))
    r2 = Rotation.from_quat(np.column_stack([q2[:, 1:], q2[:, 0]]))
    return (r1.inv() * r2).magnitude()


def _errors(name, seconds, rate_hz, earth_rate):
    b, v_true, nav = _run(name, seconds, rate_hz, earth_rate)
    att = np.max(_attitude_error_rad(nav.q_wxyz, b.truth_q_wxyz))
    vel = np.max(np.linalg.norm(nav.v_ned_m_s - v_true, axis=1))
    r = EARTH_RADIUS_M + DEFAULT_SITE.alt_m
    north = np.radians(nav.lat_deg - DEFAULT_SITE.lat_deg) * r
    east = np.radians(nav.lon_deg - DEFAULT_SITE.lon_deg) * r * np.cos(np.radians(nav.lat_deg))
    down = DEFAULT_SITE.alt_m - nav.h_m
    ned_true = cumulative_trapezoid(v_true, b.t_s, axis=0, initial=0.0)
    pos = np.max(np.linalg.norm(np.column_stack([north, east, down]) - ned_true, axis=1))
    return att, vel, pos, np.max(np.linalg.norm(ned_true, axis=1))


@pytest.mark.parametrize("earth_rate", [False, True])
def test_coordinated_turn_integrates_back_with_second_order_convergence(earth_rate):
    """Errors are pure integration error: they shrink 4× when the rate doubles (a lag would leave a floor)."""
    coarse = _errors("coordinated-turn", 60.0, 25.0, earth_rate)
    fine = _errors("coordinated-turn", 60.0, 50.0, earth_rate)
    assert fine[0] < 2e-5 and fine[1] < 0.01, f"attitude {fine[0]:.1e} rad, velocity {fine[1]:.1e} m/s"
    assert fine[2] < 0.3 and fine[3] > 300.0             # < 0.3 m after travelling > 300 m
    for c, f in zip(coarse[:2], fine[:2]):
        assert 3.0 < c / f < 5.0


def test_level_turns_with_heave_integrate_back():
    att, vel, pos, travelled = _errors("level-turns", 60.0, 50.0, earth_rate=True)
    assert att < 1e-4 and vel < 0.02 and pos < 0.5, (att, vel, pos)   # 50 Hz integration error
    assert travelled > 20.0   # circles of ~13 m radius


def test_ignoring_the_earth_rate_on_a_rotating_earth_is_detected():
    """The comparison can fail: a flat-Earth mechanisation of rotating-Earth data drifts measurably."""
    stream = open_stream("coordinated-turn", rate_hz=25.0, errors="ideal", earth_rate=True)
    b = stream.next_block(25 * 90)
    v_true = stream.scenario.velocity_ned_m_s(b.t_s)
    nav = mechanise_ned(b.t_s, b.gyro_rad_s, b.accel_m_s2, b.truth_q_wxyz[0], v_true[0], DEFAULT_SITE.lat_deg,
                        DEFAULT_SITE.lon_deg, DEFAULT_SITE.alt_m, earth_rate=False,
                        gravity_m_s2=lambda lat, h: G_SITE)
    assert np.max(np.linalg.norm(nav.v_ned_m_s - v_true, axis=1)) > 0.2


def test_static_mechanisation_holds_still_with_normal_gravity():
    stream = open_stream("static", rate_hz=20.0, errors="ideal", earth_rate=True)
    b = stream.next_block(20 * 60)
    nav = mechanise_ned(b.t_s, b.gyro_rad_s, b.accel_m_s2, b.truth_q_wxyz[0], np.zeros(3), DEFAULT_SITE.lat_deg,
                        DEFAULT_SITE.lon_deg, DEFAULT_SITE.alt_m)
    assert np.max(np.abs(nav.v_ned_m_s)) < 1e-6
    assert np.max(np.abs(nav.h_m - DEFAULT_SITE.alt_m)) < 1e-4


def test_mechanisation_rejects_mismatched_arrays():
    with pytest.raises(ValueError):
        mechanise_ned(np.arange(3.0), np.zeros((2, 3)), np.zeros((3, 3)), [1, 0, 0, 0], np.zeros(3), 0, 0, 0)
