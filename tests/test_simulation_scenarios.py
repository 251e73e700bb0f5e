"""Truth trajectories: each scenario's attitude, rate and specific force come from one consistent trajectory."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.simulation import DEFAULT_SITE, SCENARIOS, make_scenario, open_stream, simulate
from ahrsd.core.gravity import normal_gravity_m_s2

DEG = np.pi / 180.0
G_SITE = normal_gravity_m_s2(DEFAULT_SITE.lat_deg, DEFAULT_SITE.alt_m)


def rot(block) -> Rotation:
    q = block.truth_q_wxyz
    return Rotation.from_quat(np.column_stack([q[:, 1:], q[:, 0]]))  # scipy is scalar-last


def euler_deg(block):
    """(yaw, pitch, roll) in degrees, ZYX, from the truth quaternion."""
    return np.degrees(rot(block).as_euler("ZYX"))


def test_scenario_names_match_the_contract():
    assert SCENARIOS == ("static", "rate-table", "level-turns", "coordinated-turn", "tumble",
                         "auv-out-and-back", "mag-disturbance", "boat", "car", "plane")


def test_unknown_scenario_is_a_clear_error():
    with pytest.raises(ValueError, match="unknown scenario 'loop'.*static"):
        open_stream("loop")


@pytest.mark.parametrize("name", SCENARIOS)
def test_shapes_units_and_finite(name):
    b = open_stream(name, seed=3).next_block(300)
    n = 300
    for arr, shape in [(b.t_s, (n,)), (b.gyro_rad_s, (n, 3)), (b.accel_m_s2, (n, 3)), (b.mag_ut, (n, 3)),
                       (b.temp_c, (n,)), (b.truth_q_wxyz, (n, 4)), (b.truth_gyro_rad_s, (n, 3)),
                       (b.truth_mag_ut, (n, 3))]:
        assert arr.shape == shape and arr.dtype == np.float64 and np.all(np.isfinite(arr))
    np.testing.assert_allclose(np.diff(b.t_s), 1 / 819.2, rtol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(b.truth_q_wxyz, axis=1), 1.0, atol=1e-12)
    assert np.all(b.truth_q_wxyz[:, 0] >= 0)
    # Units: specific force of order g (m/s²), field of order the WMM total (µT), rates within the chip range.
    assert 5 < np.median(np.linalg.norm(b.accel_m_s2, axis=1)) < 15
    assert 20 < np.median(np.linalg.norm(b.truth_mag_ut, axis=1)) < 80
    assert np.all(np.abs(b.truth_gyro_rad_s) < 300 * DEG)
    assert np.all((b.temp_c > 0) & (b.temp_c < 60))


# Long enough to exercise every part of each scenario (rate-table: one full period of six mountings).
_DURATION_S = {"rate-table": 250.0, "auv-out-and-back": 620.0, "coordinated-turn": 160.0,
               "mag-disturbance": 60.0, "static": 5.0, "level-turns": 120.0, "tumble": 120.0,
               "boat": 210.0, "car": 175.0, "plane": 185.0}


@pytest.mark.parametrize("name", SCENARIOS)
def test_integrated_truth_rate_reproduces_truth_attitude(name):
    """Integrate ω over each 1-s window; it must land on the truth attitude at the window's end (no lag)."""
    rate = 200.0
    b = simulate(name, _DURATION_S[name], rate_hz=rate, errors="ideal")
    r = rot(b)
    m = int(rate)                       # samples per window
    nwin = (len(b) - 1) // m
    w = b.truth_gyro_rad_s
    # trapezoidal rate over each step, applied as a body-frame rotation increment
    inc = Rotation.from_rotvec(0.5 * (w[:-1] + w[1:]) / rate)
    start = r[0:nwin * m:m]
    q = start
    for j in range(m):
        q = q * inc[j:nwin * m:m]
    end = r[m:nwin * m + 1:m]
    err = (end.inv() * q).magnitude()
    assert np.max(err) < 1e-5, f"{name}: max 1-s integration error {np.max(err):.2e} rad"


@pytest.mark.parametrize("name", ["static", "mag-disturbance", "tumble"])
def test_specific_force_at_rest_is_gravity_of_the_site(name):
    b = simulate(name, 20.0, rate_hz=50.0, errors="ideal")
    np.testing.assert_allclose(np.linalg.norm(b.accel_m_s2, axis=1), G_SITE, rtol=1e-12)
    # The specific force points up: rotated to NED it is [0, 0, −g].
    f_ned = rot(b).apply(b.accel_m_s2)
    np.testing.assert_allclose(f_ned, np.tile([0, 0, -G_SITE], (len(b), 1)), atol=1e-9)


def test_static_is_level_at_rest_and_accel_z_reads_minus_g():
    b = simulate("static", 2.0, rate_hz=100.0, errors="ideal")
    np.testing.assert_allclose(b.accel_m_s2, np.tile([0, 0, -G_SITE], (len(b), 1)), atol=1e-12)
    np.testing.assert_allclose(b.truth_gyro_rad_s, 0.0, atol=1e-9)
    yaw, pitch, roll = euler_deg(b).T
    np.testing.assert_allclose(yaw, 40.0, atol=1e-9)
    np.testing.assert_allclose([pitch, roll], 0.0, atol=1e-9)


def test_level_turns_roll_pitch_within_10_deg_and_full_heading_in_a_minute():
    b = simulate("level-turns", 600.0, rate_hz=20.0, errors="ideal")
    yaw, pitch, roll = euler_deg(b).T
    assert np.max(np.abs(roll)) < 10 and np.max(np.abs(pitch)) < 10
    assert np.max(np.abs(roll)) > 5   # it does roll in the waves
    first_minute = (yaw[b.t_s < 60.0] % 360.0)
    hist, _ = np.histogram(first_minute, bins=36, range=(0, 360))
    assert np.all(hist > 0), "every 10° heading bin visited within 60 s"
    # turns through 360° again and again: unwrap the heading
    turned = np.unwrap(np.radians(yaw))
    assert (turned[-1] - turned[0]) / (2 * np.pi) > 10
    rate = np.degrees(np.gradient(turned, b.t_s))
    assert rate.min() > 3 and rate.max() < 15  # varying turn rate


def test_coordinated_turn_sustains_horizontal_acceleration_without_side_force():
    stream = open_stream("coordinated-turn", rate_hz=50.0, errors="ideal")
    sc = stream.scenario
    b = stream.next_block(int(sc.period_s * 50))
    in_turn = (b.t_s > 15.0) & (b.t_s < 73.0)   # after roll-in (straight 10 s + 4 s), before roll-out
    a_ned = sc.accel_ned_m_s2(b.t_s)
    a_h = np.linalg.norm(a_ned[:, :2], axis=1)
    np.testing.assert_allclose(a_h[in_turn], G_SITE * np.tan(30 * DEG), rtol=1e-9)
    # The accelerometer does not point at gravity: specific force tilted by the bank angle, no side force.
    tilt = np.degrees(np.arccos(-b.accel_m_s2[:, 2] / np.linalg.norm(b.accel_m_s2, axis=1)))
    np.testing.assert_allclose(tilt[in_turn], 0.0, atol=1e-6)   # along body −z (coordinated)...
    f_ned = rot(b).apply(b.accel_m_s2)
    off_vertical = np.degrees(np.arccos(-f_ned[:, 2] / np.linalg.norm(f_ned, axis=1)))
    np.testing.assert_allclose(off_vertical[in_turn], 30.0, atol=1e-6)  # ...which is 30° off the vertical
    np.testing.assert_allclose(b.accel_m_s2[:, 1], 0.0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(b.accel_m_s2[in_turn], axis=1), G_SITE / np.cos(30 * DEG), rtol=1e-9)
    roll = euler_deg(b)[:, 2]
    assert np.isclose(roll.max(), 30.0, atol=1e-6) and np.isclose(roll.min(), -30.0, atol=1e-6)


def test_tumble_covers_the_sphere_within_90_s():
    b = simulate("tumble", 90.0, rate_hz=20.0, errors="ideal")
    up_body = -b.accel_m_s2 / np.linalg.norm(b.accel_m_s2, axis=1, keepdims=True)  # gravity direction in body
    # 300 well-spread directions (Fibonacci sphere): each must have a sample close by.
    k = np.arange(300) + 0.5
    z = 1 - 2 * k / 300
    phi = np.pi * (1 + 5**0.5) * k
    probes = np.column_stack([np.sqrt(1 - z**2) * np.cos(phi), np.sqrt(1 - z**2) * np.sin(phi), z])
    nearest = np.degrees(np.arccos(np.clip((probes @ up_body.T).max(axis=1), -1, 1)))
    assert nearest.max() < 12.0, f"gap of {nearest.max():.1f}° in gravity coverage"
    fdir = b.truth_mag_ut / np.linalg.norm(b.truth_mag_ut, axis=1, keepdims=True)
    nearest_m = np.degrees(np.arccos(np.clip((probes @ fdir.T).max(axis=1), -1, 1)))
    assert nearest_m.max() < 16.0, f"gap of {nearest_m.max():.1f}° in field coverage"


def test_rate_table_turns_each_axis_both_ways_with_static_holds():
    stream = open_stream("rate-table", rate_hz=50.0, errors="ideal")
    sc = stream.scenario
    b = stream.next_block(int(sc.period_s * 50))
    w = np.degrees(b.truth_gyro_rad_s)
    for axis in range(3):
        others = [i for i in range(3) if i != axis]
        about = np.abs(np.abs(w[:, axis]) - 90.0) < 1e-6
        assert np.any(about & (w[:, axis] > 0)) and np.any(about & (w[:, axis] < 0))
        np.testing.assert_allclose(w[about][:, others], 0.0, atol=1e-6)  # a pure single-axis rotation
    still = np.linalg.norm(w, axis=1) < 1e-9
    f = b.accel_m_s2[still]
    # the six static positions: each body axis up (+g) and down (−g)
    for axis in range(3):
        assert np.any(np.abs(f[:, axis] - G_SITE) < 1e-9) and np.any(np.abs(f[:, axis] + G_SITE) < 1e-9)
    assert np.max(np.linalg.norm(b.truth_gyro_rad_s, axis=1)) < 100 * DEG  # remounting is gentle


def test_auv_legs_at_the_back_stepping_paper_headings_with_small_pitch_and_roll():
    stream = open_stream("auv-out-and-back", rate_hz=5.0, errors="ideal")
    sc = stream.scenario
    b = stream.next_block(int(2 * sc.period_s * 5))
    yaw, pitch, roll = euler_deg(b).T
    leg = sc.leg_of(b.t_s)
    np.testing.assert_allclose(yaw[leg == 0] % 360, 62.0, atol=1e-9)
    np.testing.assert_allclose(yaw[leg == 1] % 360, 243.0, atol=1e-9)
    assert np.sum(leg == 0) > 0.35 * len(b) and np.sum(leg == 1) > 0.35 * len(b)
    assert np.max(np.abs(pitch)) <= 3.0 + 1e-9 and np.max(np.abs(roll)) <= 1.5 + 1e-9
    # the vehicle moves at its speed along its heading
    v = sc.velocity_ned_m_s(b.t_s)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.5)


def test_auv_leg_duration_is_a_parameter():
    sc = make_scenario("auv-out-and-back", leg_s=60.0)
    assert sc.period_s == pytest.approx(2 * (60.0 + 60.0))
    b = open_stream(sc, rate_hz=2.0, errors="ideal").next_block(200)
    assert np.all(np.isfinite(b.truth_q_wxyz))


def test_mag_disturbance_is_a_passing_dipole():
    b = simulate("mag-disturbance", 60.0, rate_hz=50.0, errors="ideal")
    d = np.linalg.norm(b.truth_disturbance_ut, axis=1)
    assert np.max(d[b.t_s < 5.0]) < 0.05                # magnet far away at first
    assert 10.0 < d.max() < 40.0                          # strong at closest approach (0.3 m, 2 A·m²)
    passes = b.t_s[d > 5.0]
    assert passes.min() > 10.0 and np.ptp(passes) > 20.0  # two separate passes a minute
    # ideal sensor: the disturbance adds to the Earth field in the sensor reading; the truth field excludes it
    np.testing.assert_allclose(b.mag_ut, b.truth_mag_ut + b.truth_disturbance_ut, atol=1e-12)
    np.testing.assert_allclose(b.truth_gyro_rad_s, 0.0, atol=1e-9)


def test_dipole_decays_with_inverse_cube_of_distance():
    from ahrsd.simulation.magnetic import dipole_field_ut

    m = np.array([0.0, 0.0, 1.0])
    on_axis = dipole_field_ut(m, np.array([[0, 0, 0.1], [0, 0, 0.2]]))
    np.testing.assert_allclose(on_axis[0, 2], 2e-7 / 0.1**3 * 1e6)   # μ0/4π · 2m/r³ on the axis
    np.testing.assert_allclose(on_axis[0, 2] / on_axis[1, 2], 8.0)
    equator = dipole_field_ut(m, np.array([0.1, 0, 0]))
    np.testing.assert_allclose(equator, [0, 0, -1e-7 / 0.1**3 * 1e6], atol=1e-12)


@pytest.mark.parametrize("name", SCENARIOS + ("auv-diver-swing",))
def test_analytic_rate_matches_the_rotation_difference(name):
    """Scenarios compute ω analytically (Euler rates, or the rate table's composition); it must equal the
    derivative of scipy's attitude (central difference of the rotation)."""
    from ahrsd.simulation.scenarios import Scenario

    sc = make_scenario(name)
    assert type(sc).body_rate_rad_s is not Scenario.body_rate_rad_s
    # off the instants where a profile changes segment (there the difference itself is only first order)
    t = np.linspace(0.0, 300.0, 6001) + 1e-3 * np.pi
    np.testing.assert_allclose(sc.body_rate_rad_s(t), Scenario.body_rate_rad_s(sc, t), atol=1e-9)


def test_auv_diver_swing_follows_the_back_stepping_paper_test1_phases():
    stream = open_stream("auv-diver-swing", rate_hz=5.0, errors="ideal")
    sc = stream.scenario
    assert "auv-diver-swing" not in SCENARIOS and sc.period_s == pytest.approx(1330.0)
    b = stream.next_block(int(sc.period_s * 5))
    yaw, pitch, roll = euler_deg(b).T
    phase = sc.phase_of(b.t_s)
    heading_turn = np.degrees(np.ptp(np.unwrap(np.radians(yaw[phase < 3]))))
    assert heading_turn < 1e-6                                   # phases 1–2: heading held
    assert np.max(np.abs(pitch[phase == 1])) < 1e-9              # phase 1: roll only
    assert np.max(np.abs(pitch[phase == 2])) == pytest.approx(10.0, abs=0.1)
    assert np.max(np.abs(roll)) == pytest.approx(55.0, abs=0.1)
    hist, _ = np.histogram(yaw[phase == 3] % 360, bins=36, range=(0, 360))
    assert np.all(hist > 0)                                      # phase 3: full heading circle
    # consistent truth: the 1-s integration check of the other scenarios
    fine = simulate("auv-diver-swing", 30.0, rate_hz=200.0, errors="ideal", start_s=290.0)
    r = rot(fine)
    inc = Rotation.from_rotvec(0.5 * (fine.truth_gyro_rad_s[:-1] + fine.truth_gyro_rad_s[1:]) / 200.0)
    q = r[0]
    for j in range(len(inc)):
        q = q * inc[j]
    assert (r[-1].inv() * q).magnitude() < 1e-4


def test_accel_positions_walks_the_faces_twice_on_a_tilted_surface():
    """`accel-positions`: during each hold the ideal accelerometer's up direction is the position's axis tipped by
    the surface's 0.2°; a face's second placement (turned half round about the surface normal) tips it the other
    way, so the pair's mean is on the axis; still in the holds, turning between them."""
    from ahrsd.simulation.bench_positions import CORNERS, FACES

    sc = make_scenario("accel-positions")
    assert "accel-positions" not in SCENARIOS and sc.n_positions == 20
    period = sc.hold_s + sc.move_s
    b = simulate("accel-positions", 20 * period, rate_hz=50.0, errors="ideal")
    ups = []
    for k in range(20):
        hold = (b.t_s >= k * period + 1.0) & (b.t_s < k * period + sc.hold_s - 1.0)
        f = b.accel_m_s2[hold].mean(axis=0)
        ups.append(f / np.linalg.norm(f))
        assert np.abs(b.gyro_rad_s[hold]).max() < 1e-9
        assert np.abs(b.gyro_rad_s[(b.t_s > k * period + sc.hold_s + 0.5 * sc.move_s)][:5]).max() > 0.05 or k == 19
    targets = [np.array(d) / np.linalg.norm(d) for d in FACES for _ in (0, 1)] + \
        [np.array(d) / np.sqrt(3.0) for d in CORNERS]
    tips = [np.degrees(np.arccos(np.clip(u @ t, -1, 1))) for u, t in zip(ups, targets)]
    np.testing.assert_allclose(tips, 0.2, atol=1e-6)
    for k in range(0, 12, 2):
        pair = ups[k] + ups[k + 1]
        assert np.degrees(np.arccos(pair @ targets[k] / np.linalg.norm(pair))) < 1e-5
