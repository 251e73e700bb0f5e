"""A start (or restart) of ins in a hard turn (estimator/ins_start.py `levelling_lean`, `initial_covariance`):
levelling on one sample takes the turn's specific force for "up", so the start's tilt is off by the angle between
the specific force and the vertical, and at a high dip its magnetometer heading by far more. The stated 1σ's must
cover both. The truth is built here independently: a car in a flat turn and a plane in a coordinated banked turn
(specific force along the body's −z) at a 78° dip, their tilt and heading errors measured with scipy against the
attitude the start levels to."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.estimator import ins_core as core
from ahrsd.estimator.ins import Ins
from ahrsd.estimator.ins_start import initial_covariance, initial_true_attitude, levelling_force, levelling_lean
from ahrsd.core.sample import ImuSample

G_M_S2 = 9.825                              # gravity at Tromsø (69.6° N), above the standard one
FIELD_NED_UT = np.array([11.0, 1.5, 52.0])  # dip atan(52/11.1) ≈ 78°
SIGMAS = SimpleNamespace(init_sigma_tilt_rad=math.radians(5.0), init_sigma_yaw_rad=math.radians(10.0),
                         calibration_sigma_rad=math.radians(0.5), init_gyro_bias_sigma_rad_s=0.01,
                         init_accel_bias_sigma_m_s2=0.1, init_gyro_scale_sigma=0.02,
                         init_gyro_misalignment_sigma_rad=0.003, accel_axes_tilt_sigma_rad=0.004)


def _sample(yaw_deg, roll_deg, accel_ned_m_s2, rate_ned_rad_s=(0.0, 0.0, 0.0)):
    """The body-frame specific force, field and rate of a vehicle at that attitude (ZYX, pitch 0) accelerating and
    turning so, and its body→NED rotation."""
    r_nb = Rotation.from_euler("ZYX", [yaw_deg, 0.0, roll_deg], degrees=True)
    f_n = np.asarray(accel_ned_m_s2, dtype=float) - np.array([0.0, 0.0, G_M_S2])
    return r_nb.inv().apply(f_n), r_nb.inv().apply(FIELD_NED_UT), r_nb, r_nb.inv().apply(rate_ned_rad_s)


def _car_turn():
    """16 m/s heading 30°, turning right at 0.25 rad/s, body level: the centripetal ω·v points 120°."""
    a = 0.25 * 16.0
    return _sample(30.0, 0.0, a * np.array([math.cos(math.radians(120.0)), math.sin(math.radians(120.0)), 0.0]),
                   (0.0, 0.0, 0.25))


def _plane_turn():
    """A coordinated turn banked 28° heading 200°: the centripetal g·tan(bank) points 290°."""
    a = G_M_S2 * math.tan(math.radians(28.0))
    return _sample(200.0, 28.0, a * np.array([math.cos(math.radians(290.0)), math.sin(math.radians(290.0)), 0.0]),
                   (0.0, 0.0, -a / 40.0))      # at 40 m/s, turning left


def _start(f_b, m_b):
    q = initial_true_attitude(f_b, m_b, math.atan2(FIELD_NED_UT[1], FIELD_NED_UT[0]))   # the declination
    P = np.zeros((core.N_ERR, core.N_ERR))
    initial_covariance(P, SIGMAS, True, levelling_lean(f_b, m_b, 0.15))
    w, x, y, z = q
    return Rotation.from_quat([x, y, z, w]), P


def _errors(r_est, r_true):
    """Per-axis tilt error (the rotation between the true and estimated down, its N and E parts) and the ZYX
    heading error, rad."""
    down_true_b = r_true.inv().apply([0.0, 0.0, 1.0])
    down_est_b = r_est.inv().apply([0.0, 0.0, 1.0])
    axis = np.cross(down_est_b, down_true_b)
    angle = math.atan2(np.linalg.norm(axis), float(np.dot(down_est_b, down_true_b)))
    tilt_n_e = np.abs(r_true.apply(axis / max(np.linalg.norm(axis), 1e-12) * angle))[:2]
    dyaw = r_est.as_euler("ZYX")[0] - r_true.as_euler("ZYX")[0]
    return tilt_n_e, abs((dyaw + math.pi) % (2 * math.pi) - math.pi)


@pytest.mark.parametrize("turn", [_car_turn, _plane_turn])
def test_a_start_in_a_hard_turn_states_a_tilt_and_heading_sigma_that_cover_its_errors(turn):
    f_b, m_b, r_true, _ = turn()
    r_est, P = _start(f_b, m_b)
    tilt_n_e, heading = _errors(r_est, r_true)
    assert max(tilt_n_e) > math.radians(15.0)            # the case is what it claims: levelled far off
    sigma_tilt = np.sqrt(np.diag(P)[[core.E_TILT_N, core.E_TILT_E]])
    assert np.all(tilt_n_e <= sigma_tilt)                # the start's steady lean within its 1σ
    assert heading <= 3.0 * math.sqrt(P[core.E_YAW, core.E_YAW])


def test_a_start_not_accelerating_keeps_the_stated_sigmas():
    f_b, m_b, r_true, _ = _sample(75.0, 4.0, np.zeros(3))
    r_est, P = _start(f_b, m_b)
    assert P[core.E_TILT_N, core.E_TILT_N] == P[core.E_TILT_E, core.E_TILT_E] == SIGMAS.init_sigma_tilt_rad ** 2
    assert P[core.E_YAW, core.E_YAW] == SIGMAS.init_sigma_yaw_rad ** 2
    tilt_n_e, heading = _errors(r_est, r_true)
    assert max(tilt_n_e) < 1e-6 and heading < 1e-6


def _tilt_deg(f_level_b, r_true):
    up_true_b = r_true.inv().apply([0.0, 0.0, -1.0])
    c = float(np.dot(f_level_b, up_true_b)) / np.linalg.norm(f_level_b)
    return math.degrees(math.acos(min(1.0, c)))


@pytest.mark.parametrize("turn", [_car_turn, _plane_turn])
def test_in_a_steady_turn_the_start_levels_on_the_rotation_axis(turn):
    f_b, _, r_true, w_b = turn()
    w_b = w_b + np.array([0.002, -0.0015, 0.0])    # a gyro bias's worth, 0.14 °/s
    assert _tilt_deg(f_b, r_true) > 15.0            # the specific force leans by the turn
    assert _tilt_deg(levelling_force(f_b, w_b, 0.15, math.radians(0.5)), r_true) < 2.0


@pytest.mark.parametrize("rate_b", [(0.17, 0.0, 0.0), (0.0, 0.0, 0.0), "noise"])
def test_a_rate_about_another_axis_or_none_keeps_the_specific_force(rate_b):
    """A boat rolling (heaving: |f| above g), at rest (no rate), driving straight (gyro noise of 0.3 °/s that
    happens to point 5° from the specific force: the force along it is g within the tolerance)."""
    f_b, _, _, _ = _sample(75.0, 10.0, np.array([0.3, 0.0, -1.5]))
    if rate_b == "noise":
        f_b, _, _, _ = _sample(75.0, 4.0, np.zeros(3))
        axis = Rotation.from_rotvec([math.radians(5.0), 0.0, 0.0]).apply(f_b / np.linalg.norm(f_b))
        rate_b = math.radians(0.3) * axis
        assert abs(abs(float(np.dot(f_b, axis))) - 9.80665) < 0.15
    assert np.array_equal(levelling_force(f_b, np.asarray(rate_b), 0.15, math.radians(0.5)), f_b)


def test_ins_started_in_a_turn_is_levelled_on_its_axis():
    """Wiring: the filter's first attitude from a turning sample, tilt within 2° of the truth (scipy)."""
    f_b, m_b, r_true, w_b = _car_turn()
    est = Ins(declination_rad=math.atan2(FIELD_NED_UT[1], FIELD_NED_UT[0]))
    e = est.update(ImuSample(t_s=0.0, gyro_rad_s=w_b, accel_m_s2=f_b, mag_ut=m_b))
    w, x, y, z = e.q_wxyz
    up_est_b = Rotation.from_quat([x, y, z, w]).inv().apply([0.0, 0.0, -1.0])
    assert _tilt_deg(up_est_b, r_true) < 2.0
