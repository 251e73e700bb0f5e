"""Vehicle scenarios (boat, car, plane): position, velocity, acceleration, attitude and the sensed rate and specific
force come from one consistent trajectory on a spherical Earth (R0 = 6 378 137 m).

Truth here is computed independently of the simulator's code: finite differences and trapezoid integrals of its
own outputs, scipy's Rotation, and the textbook relations (coordinated bank atan(Vω/g), eq. 17 position rates).
"""

from __future__ import annotations

import datetime as dt

import numpy as np
import pytest
from scipy.integrate import cumulative_trapezoid
from scipy.spatial.transform import Rotation

from ahrsd.simulation import DEFAULT_SITE, SCENARIOS, Site, make_scenario, open_stream, simulate
from ahrsd.core.gravity import EARTH_RADIUS_M, normal_gravity_m_s2
from ahrsd.core.gravity import EARTH_RATE_RAD_S
from ahrsd.simulation.strapdown import mechanise_ned

VEHICLES = ("boat", "car", "plane")
MOVING = VEHICLES + ("level-turns", "coordinated-turn", "auv-out-and-back")
G_SITE = DEFAULT_SITE.gravity_m_s2


def rot(q_wxyz) -> Rotation:
    return Rotation.from_quat(np.column_stack([q_wxyz[:, 1:], q_wxyz[:, 0]]))


def euler_deg(block):
    """(yaw, pitch, roll) in degrees, ZYX, from the truth quaternion (scipy)."""
    return np.degrees(rot(block.truth_q_wxyz).as_euler("ZYX")).T


def full_period(name, rate_hz, **kw):
    stream = open_stream(name, rate_hz=rate_hz, errors="ideal", **kw)
    period = getattr(stream.scenario, "period_s", 120.0)
    return stream, stream.next_block(int(period * rate_hz) + 1)


def test_vehicles_are_scenarios_of_the_contract():
    assert set(VEHICLES) <= set(SCENARIOS)
    for name in VEHICLES:
        sc = make_scenario(name)
        assert 150.0 <= sc.period_s <= 300.0 and sc.rotating_earth   # a few minutes each, on a rotating Earth
        assert open_stream(name).earth_rate and not open_stream(name, earth_rate=False).earth_rate
    assert not open_stream("level-turns").earth_rate   # the existing scenarios keep their flat-Earth default


@pytest.mark.parametrize("name", MOVING)
def test_position_changes_at_the_truth_velocity(name):
    """Central differences of lat/lon/alt, scaled by the position rates L̇ = V_N/(R0+h), λ̇ = V_E/((R0+h) cos L), give back the truth velocity."""
    rate = 50.0
    _, b = full_period(name, rate)
    dt_s = 1.0 / rate
    r = EARTH_RADIUS_M + b.truth_alt_m[1:-1]
    lat = np.radians(b.truth_lat_deg)
    v_n = (lat[2:] - lat[:-2]) / (2 * dt_s) * r
    v_e = np.radians(b.truth_lon_deg[2:] - b.truth_lon_deg[:-2]) / (2 * dt_s) * r * np.cos(lat[1:-1])
    v_d = -(b.truth_alt_m[2:] - b.truth_alt_m[:-2]) / (2 * dt_s)
    err = np.column_stack([v_n, v_e, v_d]) - b.truth_vel_ned_m_s[1:-1]
    # central-difference error dt²/6 · |d²v/dt²| stays below 1e-4 m/s for these smooth trajectories
    assert np.max(np.abs(err)) < 1e-3, f"{name}: {np.max(np.abs(err)):.2e} m/s"
    assert b.truth_lat_deg[0] == DEFAULT_SITE.lat_deg and b.truth_lon_deg[0] == DEFAULT_SITE.lon_deg


@pytest.mark.parametrize("name", MOVING)
def test_velocity_is_the_integral_of_the_acceleration(name):
    sc = make_scenario(name)
    period = getattr(sc, "period_s", 120.0)
    t = np.arange(0.0, period, 0.005)
    v, a = sc.velocity_ned_m_s(t), sc.accel_ned_m_s2(t)
    integrated = v[0] + cumulative_trapezoid(a, t, axis=0, initial=0.0)
    assert np.max(np.abs(integrated - v)) < 1e-4
    h = 1e-4
    fd = (sc.velocity_ned_m_s(t + h) - sc.velocity_ned_m_s(t - h)) / (2 * h)
    assert np.max(np.abs(fd - a)) < 1e-5


def test_static_scenarios_stay_at_the_site_with_zero_velocity():
    for name in ("static", "tumble", "rate-table", "mag-disturbance"):
        b = simulate(name, 5.0, rate_hz=20.0, errors="ideal")
        assert np.all(b.truth_vel_ned_m_s == 0.0)
        assert np.all(b.truth_lat_deg == DEFAULT_SITE.lat_deg) and np.all(b.truth_lon_deg == DEFAULT_SITE.lon_deg)
        assert np.all(b.truth_alt_m == DEFAULT_SITE.alt_m)


def test_plane_flies_coordinated_with_the_specific_force_on_body_minus_z_in_steady_turns():
    stream, b = full_period("plane", 50.0, earth_rate=False)   # flat Earth: no Coriolis side force
    v = b.truth_vel_ned_m_s
    speed = np.hypot(v[:, 0], v[:, 1])
    course = np.unwrap(np.arctan2(v[:, 1], v[:, 0]))
    omega = np.gradient(course, b.t_s)
    d_omega = np.gradient(omega, b.t_s)
    yaw, pitch, roll = euler_deg(b)
    f = b.truth_accel_m_s2
    # Coordinated everywhere (also in climbs, roll-in and speed changes): no lateral specific force.
    assert np.max(np.abs(f[:, 1])) < 1e-6
    steady = (np.abs(omega) > 0.1) & (np.abs(d_omega) < 1e-6) & (np.abs(v[:, 2]) < 1e-9) & \
             (np.abs(np.gradient(speed, b.t_s)) < 1e-6)
    assert steady.sum() > 1000                                       # > 20 s of steady level turning
    expected_bank = np.degrees(np.arctan(speed * omega / G_SITE))
    np.testing.assert_allclose(roll[steady], expected_bank[steady], atol=0.01)
    assert 20.0 <= np.min(np.abs(roll[steady])) and np.max(np.abs(roll[steady])) <= 30.0
    np.testing.assert_allclose(f[steady, 0], 0.0, atol=1e-3)        # on body −z ...
    np.testing.assert_allclose(-f[steady, 2], G_SITE / np.cos(np.radians(roll[steady])), rtol=1e-6)
    # climbs with pitch = flight-path angle, speeds 20–26 m/s, the height lost again
    np.testing.assert_allclose(pitch, np.degrees(np.arctan2(-v[:, 2], speed)), atol=1e-9)
    assert np.min(speed) == pytest.approx(20.0) and np.max(speed) == pytest.approx(26.0)
    assert np.ptp(b.truth_alt_m) == pytest.approx(48.0, abs=0.05)
    assert abs(b.truth_alt_m[-1] - b.truth_alt_m[0]) < 0.05


def test_car_accelerates_brakes_turns_at_0_4_g_and_its_suspension_follows():
    stream, b = full_period("car", 50.0)
    v = b.truth_vel_ned_m_s
    speed = np.hypot(v[:, 0], v[:, 1])
    assert np.all(speed[b.t_s < 5.0] == 0.0) and np.max(speed) == pytest.approx(20.0)
    a = stream.scenario.accel_ned_m_s2(b.t_s)
    yaw, pitch, roll = euler_deg(b)
    heading = np.radians(yaw)
    along = a[:, 0] * np.cos(heading) + a[:, 1] * np.sin(heading)
    lateral = -a[:, 0] * np.sin(heading) + a[:, 1] * np.cos(heading)
    g = 9.80665
    assert np.max(np.abs(lateral)) / g == pytest.approx(0.40, abs=0.01)
    assert np.min(along) / g < -0.6 and np.max(along) / g > 0.35          # hard braking, brisk acceleration
    moving = speed > 1.0
    course = np.degrees(np.arctan2(v[:, 1], v[:, 0]))
    assert np.max(np.abs((course - yaw + 180) % 360 - 180)[moving]) < 1e-6   # no side slip
    # suspension: nose down when braking, up when accelerating; rolls out of the turn
    grade = np.degrees(np.arctan2(-v[:, 2], np.maximum(speed, 1e-9)))
    squat = pitch - grade
    assert np.corrcoef(squat, along)[0, 1] > 0.999 and np.max(np.abs(squat)) > 1.0
    turning = np.abs(lateral) > 2.0
    assert np.all(np.sign(roll[turning]) == -np.sign(lateral[turning])) and np.max(np.abs(roll)) > 1.5
    assert np.ptp(b.truth_alt_m) > 2.0                                     # the hill


def test_boat_turns_in_waves_and_its_course_over_ground_is_not_its_heading():
    stream, b = full_period("boat", 50.0)
    v = b.truth_vel_ned_m_s
    yaw, pitch, roll = euler_deg(b)
    heading_rate = np.degrees(np.gradient(np.unwrap(np.radians(yaw)), b.t_s))
    assert 6.5 < np.max(np.abs(heading_rate)) <= 7.0
    through_water = v - np.asarray(stream.scenario.current_ned_m_s)
    speed_water = np.hypot(through_water[:, 0], through_water[:, 1])
    assert np.min(speed_water) == pytest.approx(4.0) and np.max(speed_water) == pytest.approx(5.0)
    crab = (np.degrees(np.arctan2(v[:, 1], v[:, 0])) - yaw + 180) % 360 - 180
    assert np.median(np.abs(crab)) > 3.0 and np.max(np.abs(crab)) > 8.0
    assert np.max(np.abs(roll)) > 5.0 and np.max(np.abs(pitch)) > 2.0      # waves
    assert np.ptp(b.truth_alt_m) > 0.7                                     # heave
    assert np.max(np.abs(v[:, 2])) > 0.3


def _ned_offset_m(lat_deg, lon_deg, alt_m):
    """North/east/down of each point from the site (spherical Earth R0, small offsets)."""
    r = EARTH_RADIUS_M + alt_m
    north = np.radians(lat_deg - DEFAULT_SITE.lat_deg) * r
    east = np.radians(lon_deg - DEFAULT_SITE.lon_deg) * r * np.cos(np.radians(lat_deg))
    return np.column_stack([north, east, DEFAULT_SITE.alt_m - alt_m])


# 60-s windows with the most going on: the car from rest through its first 0.4 g turn, the plane's climb (where
# g(h) changes) and its 29° left turn
_STRAPDOWN_START_S = {"boat": 0.0, "car": 0.0, "plane": 50.0}


def _strapdown_errors(name, rate_hz, seconds=60.0):
    stream = open_stream(name, rate_hz=rate_hz, errors="ideal", vehicle_iron=None, start_s=_STRAPDOWN_START_S[name])
    b = stream.next_block(int(seconds * rate_hz) + 1)
    nav = mechanise_ned(b.t_s, b.gyro_rad_s, b.accel_m_s2, b.truth_q_wxyz[0], b.truth_vel_ned_m_s[0],
                        b.truth_lat_deg[0], b.truth_lon_deg[0], b.truth_alt_m[0])   # Earth rate, g(L, h)
    att = np.max((rot(nav.q_wxyz).inv() * rot(b.truth_q_wxyz)).magnitude())
    vel = np.max(np.linalg.norm(nav.v_ned_m_s - b.truth_vel_ned_m_s, axis=1))
    pos = np.max(np.linalg.norm(_ned_offset_m(nav.lat_deg, nav.lon_deg, nav.h_m)
                                - _ned_offset_m(b.truth_lat_deg, b.truth_lon_deg, b.truth_alt_m), axis=1))
    travelled = np.sum(np.linalg.norm(np.diff(_ned_offset_m(b.truth_lat_deg, b.truth_lon_deg, b.truth_alt_m),
                                              axis=0), axis=1))
    return att, vel, pos, travelled


@pytest.mark.parametrize("name", VEHICLES)
def test_strapdown_of_the_ideal_sensors_reproduces_the_trajectory(name):
    """The NED mechanisation (Groves 2nd ed. §5.4) with Earth rate, transport rate and g(L, h) integrates the simulated ideal
    gyro and accelerometer back into the truth over 60 s. The only error left is the mechanisation's own
    second-order integration error: it shrinks ~4× when the rate doubles (a missing Coriolis, transport or
    gravity term would leave a floor: 2 ω_ie V alone is 3e-3 m/s² at 25 m/s, 5 m after 60 s). Bounds: the
    100-Hz errors measured (≤ 9.5e-6 rad, ≤ 1.6e-3 m/s, ≤ 0.04 m over 0.3–1.5 km) with a 3× margin."""
    coarse = _strapdown_errors(name, 50.0)
    fine = _strapdown_errors(name, 100.0)
    att, vel, pos, travelled = fine
    assert att < 3e-5 and vel < 5e-3 and pos < 0.12, f"{name}: {att:.1e} rad, {vel:.1e} m/s, {pos:.2f} m"
    assert travelled > 200.0
    for c, f in zip(coarse[:3], fine[:3]):
        assert 2.5 < c / f < 5.0, (name, coarse, fine)


def test_a_rotating_earth_trajectory_is_not_flat():
    """The strapdown check can fail: a flat-Earth mechanisation of the plane's data drifts off the truth."""
    stream = open_stream("plane", rate_hz=50.0, errors="ideal")
    b = stream.next_block(50 * 60)
    nav = mechanise_ned(b.t_s, b.gyro_rad_s, b.accel_m_s2, b.truth_q_wxyz[0], b.truth_vel_ned_m_s[0],
                        b.truth_lat_deg[0], b.truth_lon_deg[0], b.truth_alt_m[0], earth_rate=False)
    assert np.max(np.linalg.norm(nav.v_ned_m_s - b.truth_vel_ned_m_s, axis=1)) > 0.05


def test_another_site_moves_the_start_gravity_and_earth_rate():
    site = Site(-33.9, 18.4, 20.0, dt.date(2027, 6, 1))     # Cape Town
    b = simulate("car", 2.0, rate_hz=20.0, errors="ideal", site=site, vehicle_iron=None)
    assert b.truth_lat_deg[0] == -33.9 and b.truth_lon_deg[0] == 18.4 and b.truth_alt_m[0] == 20.0
    # at rest for the first 5 s: the accelerometer reads g there, the gyro the Earth rate at −33.9°
    np.testing.assert_allclose(np.linalg.norm(b.accel_m_s2, axis=1), normal_gravity_m_s2(-33.9, 20.0), rtol=1e-12)
    gyro_ned = rot(b.truth_q_wxyz).apply(b.gyro_rad_s)
    lat = np.radians(-33.9)
    np.testing.assert_allclose(gyro_ned, np.tile(EARTH_RATE_RAD_S * np.array([np.cos(lat), 0, -np.sin(lat)]),
                                                 (len(b), 1)), atol=1e-10)
    plane = open_stream("plane", site=site).scenario
    assert plane.gravity_m_s2 == site.gravity_m_s2                     # bank coordinated with the local g


def test_position_does_not_depend_on_block_sizes_rates_or_start():
    a = open_stream("plane", rate_hz=40.0, errors="ideal")
    whole = a.next_block(4000)
    s = open_stream("plane", rate_hz=40.0, errors="ideal")
    from ahrsd.simulation import SensorBlock
    parts = SensorBlock.concatenate([s.next_block(k) for k in (1, 299, 700, 3000)])
    for f in ("truth_lat_deg", "truth_lon_deg", "truth_alt_m", "truth_vel_ned_m_s", "accel_m_s2"):
        np.testing.assert_array_equal(getattr(parts, f), getattr(whole, f))
    late = open_stream("plane", rate_hz=40.0, errors="ideal", start_s=50.0).next_block(10)
    np.testing.assert_allclose(late.truth_lat_deg, whole.truth_lat_deg[2000:2010], rtol=0, atol=1e-12)
    exact = a.truth_at(whole.t_s[3990:])
    np.testing.assert_allclose(exact.lon_deg, whole.truth_lon_deg[3990:], rtol=0, atol=1e-12)
    np.testing.assert_allclose(exact.q_wxyz, whole.truth_q_wxyz[3990:], atol=1e-12)
