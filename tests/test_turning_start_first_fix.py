"""A start of ins in a hard turn whose rotation axis is refused (estimator/ins_start.py `first_fix_in_turn`): the
start levels on the specific force, which leans by the turn's centripetal acceleration, and at a high dip the
magnetometer's heading read at that tilt is off by most of a half turn. At the first fix the speed tells the
centripetal ω × v: the start is levelled again on f − ω × v (`centripetal_levelling_force`), or, when that cannot
be done, its tilt and the magnetometer's yaw 1σ widen to the lean it cannot exclude (`first_fix_lean`,
`widen_for_lean`). The truth is the simulator's (a car at Fairbanks whose start the axis test refuses: the force
along the rate's axis 0.33 m/s² from g) or built here with scipy rotations."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.core.estimate import EstimateFlags
from ahrsd.estimator import ins_core as core
from ahrsd.estimator.ins import Ins
from ahrsd.estimator.ins_start import centripetal_levelling_force, first_fix_lean, levelling_force, widen_for_lean
from bench.vehicle_accuracy import estimates_in_arrival_order, simulate_vehicle, tilt_heading_errors_deg

G_M_S2 = 9.80665


@pytest.fixture(scope="module")
def car_turning():
    """3 s of the car at Fairbanks from 75 s into its scenario (seed 5), in a 13.5 °/s turn at 15 m/s."""
    return simulate_vehicle("car", 3.0, 5, "64.84,-147.72", mag="calibrated", start_s=75.0)


def _run(run, fixes_from_s=0.0, **params):
    """ins over the run: per sample the tilt and heading errors against the simulator's truth (deg), the tilt 1σ
    (roll and pitch in quadrature) and yaw 1σ (deg), whether GNSS aided it (from the first fix) and the horizontal
    velocity error (m/s, NaN before)."""
    est = Ins(declination_rad=run.declination_rad, lever_arm_m=run.lever_arm_m,
              mag_calibration_sigma_rad=run.mag_calibration_sigma_rad, **params)
    n = len(run.t_s)
    q, s_tilt, s_yaw, aided = np.empty((n, 4)), np.empty(n), np.empty(n), np.zeros(n, dtype=bool)
    dv = np.full(n, np.nan)
    fixes = [f for f in run.fixes if f.t_s - run.t_s[0] >= fixes_from_s]
    for k, e in estimates_in_arrival_order(est, run, fixes):
        q[k] = e.q_wxyz
        aided[k] = bool(e.flags & EstimateFlags.GNSS_AIDED)
        if e.nav is not None:
            dv[k] = float(np.linalg.norm(e.nav.vel_ned_m_s[:2] - run.truth_vel_ned_m_s[k, :2]))
        s_tilt[k] = math.degrees(math.hypot(e.sigma_rpy_rad[0], e.sigma_rpy_rad[1]))
        s_yaw[k] = math.degrees(e.sigma_rpy_rad[2])
    tilt, hdg = tilt_heading_errors_deg(q, run.truth_q_wxyz, run.declination_rad)
    return SimpleNamespace(tilt=tilt, hdg=hdg, s_tilt=s_tilt, s_yaw=s_yaw, aided=aided, dv=dv)


def test_the_start_is_refused_the_axis(car_turning):
    """The case the first fix mends: the start levels on the specific force, 20° from the vertical."""
    est = Ins()
    f, w = car_turning.accel_m_s2[0], car_turning.gyro_rad_s[0]
    level = levelling_force(f, w, 3.0 * est.params.init_accel_bias_sigma_m_s2, est.params.init_gyro_bias_sigma_rad_s)
    assert np.array_equal(level, f)


def test_levelled_again_at_the_first_fix_the_tilt_and_heading_are_right_and_covered(car_turning):
    r = _run(car_turning)
    tilt, hdg, s_tilt, s_yaw, before, after = r.tilt, r.hdg, r.s_tilt, r.s_yaw, ~r.aided, r.aided
    assert np.min(tilt[before]) > 15.0                      # levelled on the turn's force until the fix
    assert np.all(tilt[after] <= 3.0 * s_tilt[after])
    assert np.all(np.abs(hdg[after]) <= 3.0 * s_yaw[after])
    assert np.max(tilt[after]) < 10.0                       # on gravity from it (the fixes' lag leans it a little)


def test_levelled_again_the_velocity_is_carried_over_the_fix_delay(car_turning):
    """The fix sets the velocity it had at its own time; levelled on the force, the start saw no horizontal
    acceleration over the fix's delay: levelled again, the turn's acceleration over that delay is added."""
    r = _run(car_turning)
    k = int(np.flatnonzero(r.aided)[0])
    assert r.dv[k] < 0.1


def test_without_the_magnetometer_the_first_fix_widens_the_tilt_sigma(car_turning):
    """No heading to read at a new tilt: the start keeps its tilt, and its 1σ covers it."""
    r = _run(car_turning, mag_enabled=False)
    tilt, s_tilt = r.tilt, r.s_tilt
    k = int(np.flatnonzero(r.aided)[0])                     # the sample right after the first fix
    assert tilt[k] > 15.0
    assert tilt[k] <= 3.0 * s_tilt[k]


def test_a_first_fix_long_after_the_start_widens_instead(car_turning):
    """2 s after the start the attitude is the levelling's over many samples, no longer the start's: the first
    fix then does not level it again (nor read the magnetometer again), and widens its 1σ to the lean."""
    r = _run(car_turning, fixes_from_s=2.0)
    tilt, s_tilt = r.tilt, r.s_tilt
    k = int(np.flatnonzero(r.aided)[0])
    assert tilt[k] > 10.0
    assert tilt[k] <= 3.0 * s_tilt[k]


def _turn(yaw_deg, speed_m_s, rate_down_rad_s, forward=1.0):
    """A car driving level at `speed_m_s` along ±its body x axis, turning at `rate_down_rad_s` about the vertical:
    its body-frame specific force, rate and velocity, and its up vector in the body frame (scipy)."""
    r_nb = Rotation.from_euler("ZYX", [yaw_deg, 0.0, 0.0], degrees=True)
    w_n = np.array([0.0, 0.0, rate_down_rad_s])
    v_n = r_nb.apply([forward * speed_m_s, 0.0, 0.0])
    f_n = np.cross(w_n, v_n) - np.array([0.0, 0.0, G_M_S2])
    return r_nb.inv().apply(f_n), r_nb.inv().apply(w_n), v_n, r_nb.inv().apply([0.0, 0.0, -1.0])


def _angle_deg(u, v):
    return math.degrees(math.atan2(np.linalg.norm(np.cross(u, v)), float(np.dot(u, v))))


def test_the_force_less_the_centripetal_part_is_the_vertical():
    f, w, v, up = _turn(30.0, 16.0, 0.25)
    assert _angle_deg(f, up) > 20.0
    fc = centripetal_levelling_force(f, w, float(np.linalg.norm(v)))
    assert _angle_deg(fc, up) < 0.01


def test_reversing_or_rolling_is_not_levelled_again():
    f, w, v, _ = _turn(30.0, 16.0, 0.25, forward=-1.0)     # backwards: ω × x̂ has the wrong sign
    assert centripetal_levelling_force(f, w, float(np.linalg.norm(v))) is None
    roll = np.array([0.3, 0.0, 0.0])                        # a rate about the forward axis has no centripetal part
    assert centripetal_levelling_force(np.array([0.0, 0.0, -G_M_S2]), roll, 5.0) is None


def test_the_lean_the_first_fix_tells():
    f, w, v, _ = _turn(30.0, 16.0, 0.25)
    q = np.array([math.cos(math.radians(15.0)), 0.0, 0.0, math.sin(math.radians(15.0))])    # yaw 30°, level
    assert math.degrees(first_fix_lean(q, w, v, f)) == pytest.approx(
        math.degrees(math.atan2(0.25 * 16.0, G_M_S2) + (math.hypot(4.0, G_M_S2) - G_M_S2) / G_M_S2), abs=1e-6)
    assert first_fix_lean(q, np.array([0.3, 0.0, 0.0]), v, np.array([0.0, 0.0, -G_M_S2])) < 1e-9


def test_widening_covers_the_lean_and_leaves_the_yaw_to_the_coupling():
    """The tilt 1σ widened to the lean; the yaw is not widened here (the filter couples it to the widened tilt
    through the dip next: ins_start.couple_yaw_to_tilt, tests/test_start_yaw_at_first_fix.py)."""
    P = np.eye(core.N_ERR) * math.radians(1.0) ** 2
    P[core.E_TILT_N, core.E_YAW] = P[core.E_YAW, core.E_TILT_N] = 1e-6
    lean = math.radians(20.0)
    assert widen_for_lean(P, lean)
    assert math.sqrt(P[core.E_TILT_N, core.E_TILT_N]) == pytest.approx(lean)
    assert math.sqrt(P[core.E_TILT_E, core.E_TILT_E]) == pytest.approx(lean)
    assert P[core.E_YAW, core.E_YAW] == math.radians(1.0) ** 2
    assert P[core.E_TILT_N, core.E_YAW] == 0.0
    small = np.eye(core.N_ERR) * math.radians(10.0) ** 2
    assert not widen_for_lean(small, math.radians(5.0))
    assert small[core.E_TILT_N, core.E_TILT_N] == pytest.approx(math.radians(10.0) ** 2)
