"""The ten-accelerometer gyro-free array (Ghasemzadeh & Heyrani Nobari 2011) and inertial-frame navigation
against a worked example."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.simulation import open_stream
from ahrsd.simulation.accel_array import AccelArray, solve_seed001
from ahrsd.simulation.strapdown import mechanise_inertial

D = 0.1  # arm length, m (the paper does not give one)


@pytest.fixture(scope="module")
def tumble():
    s = open_stream("tumble", rate_hz=50.0, errors="ideal")
    b = s.next_block(50 * 60)
    return b, s.scenario.body_angular_accel_rad_s2(b.t_s)


def test_array_equations_13_14_17_19_hold_on_a_tumble(tumble):
    b, wdot = tumble
    arr = AccelArray.seed001(D)
    sol = solve_seed001(arr.specific_force(b.truth_accel_m_s2, b.truth_gyro_rad_s, wdot), D)
    np.testing.assert_allclose(sol.f_b, b.truth_accel_m_s2, atol=1e-12)                 # eq. 13
    np.testing.assert_allclose(sol.rate_sq, b.truth_gyro_rad_s**2, atol=1e-12)           # eq. 14
    np.testing.assert_allclose(sol.rate_abs, np.abs(b.truth_gyro_rad_s), atol=1e-6)
    np.testing.assert_allclose(sol.q_dot, wdot[:, 1], atol=1e-11)                        # eq. 17
    np.testing.assert_allclose(sol.p_dot, wdot[:, 0], atol=1e-11)                        # eq. 19
    assert np.max(np.abs(wdot)) > 0.3   # the tumble does accelerate in rotation


def test_angular_acceleration_is_the_derivative_of_the_rate(tumble):
    b, wdot = tumble
    numeric = np.gradient(b.truth_gyro_rad_s, b.t_s, axis=0)
    np.testing.assert_allclose(wdot[5:-5], numeric[5:-5], atol=2e-3)


def test_equal_biases_cancel_in_the_rates_and_a_spread_gives_eq24():
    arr = AccelArray.seed001(D)
    n = 4
    zero = np.zeros((n, 3))
    still = arr.specific_force(zero, zero, zero)
    same = solve_seed001(still + 1e-3, D)
    np.testing.assert_allclose(same.rate_sq, 0.0, atol=1e-15)            # a common bias cancels in the rate products
    np.testing.assert_allclose(same.f_b, 1e-3)                            # eq. 22
    # adversarial signs for p (eq. 23): +F1 −F2 −F3 +F4 −F5 +F6 → Δp² = 6F/(4d) = 1.5 F/d; F = 1 µm/s²
    F = 1e-6
    bias = F * np.array([1, -1, -1, 1, -1, 1, 0, 0, 0, 0])
    worst = solve_seed001(still + bias, D)
    np.testing.assert_allclose(worst.rate_abs[:, 0], np.sqrt(1.5 * F / D))
    assert np.sqrt(1.5 * F / D) == pytest.approx(3.9e-3, abs=0.05e-3)     # worked: √(1.5·F/d) at d = 0.10 m


def test_misaligned_axes_leak_cross_axis_force():
    arr = AccelArray.seed001(D)
    tilt = np.zeros((10, 3))
    tilt[0, 1] = np.radians(0.1)      # m1 tilted 0.1° about b2 (in the b1b3 plane)
    f = np.array([[50.0, 10.0, 10.0]])
    zero = np.zeros((1, 3))
    diff = arr.tilted(tilt).specific_force(f, zero, zero) - arr.specific_force(f, zero, zero)
    # axis b1 rotated by θ about b2 becomes [cos θ, 0, −sin θ]: reading changes by 50(cos θ − 1) − 10 sin θ
    th = np.radians(0.1)
    assert diff[0, 0] == pytest.approx(50 * (np.cos(th) - 1) - 10 * np.sin(th))
    np.testing.assert_allclose(diff[0, 1:], 0.0)


# worked example: a^b = [50, 10, 10] m/s², ω = [1, 2, 3] rad/s, from rest, identity attitude, no gravity.
GYROFREE_WORKED_EXAMPLE = [
    (1, (8.337, 18.093, 1.826), (-0.629, 33.186, 11.419)),
    (2, (14.987, 45.885, 31.081), (24.506, 33.881, 35.910)),
    (5, (85.718, 228.945, 235.464), (34.094, 71.690, 107.509)),
    (10, (350.068, 815.019, 1006.632), (68.207, 143.573, 214.882)),
]


def test_inertial_mechanisation_reproduces_the_worked_trajectory():
    t = np.arange(10001) * 1e-3
    nav = mechanise_inertial(t, np.tile([1.0, 2.0, 3.0], (len(t), 1)), np.tile([50.0, 10.0, 10.0], (len(t), 1)),
                             [1, 0, 0, 0], np.zeros(3), np.zeros(3))
    for sec, pos, vel in GYROFREE_WORKED_EXAMPLE:
        k = sec * 1000
        np.testing.assert_allclose(nav.p_m[k], pos, atol=2e-3)
        np.testing.assert_allclose(nav.v_m_s[k], vel, atol=2e-3)
    q = nav.q_wxyz[-1]
    np.testing.assert_allclose(q, [0.99004, -0.03763, -0.07526, -0.11289], atol=1e-5)
    yaw, pitch, roll = np.degrees(Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_euler("ZYX"))
    assert (roll, pitch, yaw) == pytest.approx((-3.339, -9.063, -12.746), abs=1e-3)
    # along the spin axis the motion is uniformly accelerated: ½ (a·ŵ) t²
    w_hat = np.array([1.0, 2.0, 3.0]) / np.sqrt(14)
    assert nav.p_m[-1] @ w_hat == pytest.approx(0.5 * (np.array([50.0, 10, 10]) @ w_hat) * 100, rel=1e-4)


def test_inertial_mechanisation_with_gravity_holds_a_resting_sensor():
    t = np.arange(200) * 0.01
    nav = mechanise_inertial(t, np.zeros((200, 3)), np.tile([0.0, 0.0, -9.8], (200, 1)), [1, 0, 0, 0],
                             np.zeros(3), np.zeros(3), gravity_i_m_s2=[0.0, 0.0, 9.8])
    np.testing.assert_allclose(nav.p_m, 0.0, atol=1e-12)


def test_bad_array_inputs_are_rejected():
    with pytest.raises(ValueError):
        solve_seed001(np.zeros((3, 9)), D)
    with pytest.raises(ValueError):
        AccelArray(np.zeros((2, 3)), np.zeros((2, 3)))
