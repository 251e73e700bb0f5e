"""Rotation maths: conventions pinned against scipy (independent truth) and worked numbers, plus property tests."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from ahrsd.core import angles
from ahrsd.estimator import rotations as rot

PROPS = settings(derandomize=True, max_examples=60, deadline=None)

finite = st.floats(-1.0, 1.0, allow_nan=False)


@st.composite
def unit_quats(draw):
    v = np.array([draw(finite) for _ in range(4)])
    if np.linalg.norm(v) < 1e-3:
        v = np.array([1.0, 0.0, 0.0, 0.0])
    return v / np.linalg.norm(v)


@st.composite
def rotvecs(draw, max_angle=math.pi - 1e-6):
    axis = np.array([draw(finite) for _ in range(3)])
    if np.linalg.norm(axis) < 1e-3:
        axis = np.array([0.0, 0.0, 1.0])
    angle = draw(st.one_of(st.floats(0.0, max_angle), st.floats(0.0, 1e-7)))
    return axis / np.linalg.norm(axis) * angle


def scipy_rot(q_wxyz) -> Rotation:
    return Rotation.from_quat(rot.quat_to_scalar_last(q_wxyz))


# ----------------------------------------------------------------------------- conventions, worked numbers
def test_yaw_90_maps_body_forward_to_east():
    q = rot.euler_to_quat(0.0, 0.0, math.pi / 2)
    np.testing.assert_allclose(rot.quat_rotate(q, [1.0, 0, 0]), [0, 1.0, 0], atol=1e-15)


def test_positive_pitch_raises_nose():
    # Nose up by 30°: body x points up (negative down component) in NED.
    v = rot.quat_rotate(rot.euler_to_quat(0.0, math.radians(30), 0.0), [1.0, 0, 0])
    np.testing.assert_allclose(v, [math.cos(math.radians(30)), 0, -0.5], atol=1e-15)


def test_positive_roll_drops_right_wing():
    v = rot.quat_rotate(rot.euler_to_quat(math.radians(30), 0.0, 0.0), [0, 1.0, 0])
    np.testing.assert_allclose(v, [0, math.cos(math.radians(30)), 0.5], atol=1e-15)


def test_dcm_matches_the_zyx_full_form_and_its_euler_inverse():
    roll, pitch, yaw = 0.3, -0.2, 2.5
    c = rot.euler_to_dcm(roll, pitch, yaw)
    np.testing.assert_allclose(c, Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix(), atol=1e-15)
    assert math.isclose(c[2, 0], -math.sin(pitch))  # C31 = −sin θ
    np.testing.assert_allclose(rot.dcm_to_euler(c), [roll, pitch, yaw], atol=1e-14)


def test_small_angle_dcm_matches_the_first_order_form():
    a = 1e-4
    c = rot.euler_to_dcm(a, 2 * a, 3 * a)
    small = np.array([[1, -3 * a, 2 * a], [3 * a, 1, -a], [-2 * a, a, 1]])
    np.testing.assert_allclose(c, small, atol=1e-7)  # second-order terms are ~(3a)²/2


def test_constant_rate_worked_example_final_quaternion_and_euler():
    # worked example: constant ω = [1, 2, 3] rad/s for 10 s from identity, scalar-last final quaternion,
    # ZYX Euler roll −3.339°, pitch −9.063°, yaw −12.746°.
    q = rot.quat_exp(np.array([1.0, 2.0, 3.0]) * 10.0)
    q_xyzw = rot.quat_to_scalar_last(rot.quat_canonical(q))
    np.testing.assert_allclose(q_xyzw, [-0.03763, -0.07526, -0.11289, 0.99004], atol=1e-5)
    np.testing.assert_allclose(np.degrees(rot.quat_to_euler(q)), [-3.339, -9.063, -12.746], atol=1e-3)


def test_scalar_last_quaternion_dcm_formula_is_quat_to_dcm():
    e = np.array([0.1, -0.5, 0.3, 0.8])
    e /= np.linalg.norm(e)
    e1, e2, e3, e4 = e
    c44 = np.array([
        [1 - 2 * (e2**2 + e3**2), 2 * (e1 * e2 - e3 * e4), 2 * (e1 * e3 + e2 * e4)],
        [2 * (e1 * e2 + e3 * e4), 1 - 2 * (e1**2 + e3**2), 2 * (e2 * e3 - e1 * e4)],
        [2 * (e1 * e3 - e2 * e4), 2 * (e2 * e3 + e1 * e4), 1 - 2 * (e1**2 + e2**2)],
    ])
    np.testing.assert_allclose(rot.quat_to_dcm(rot.quat_from_scalar_last(e)), c44, atol=1e-15)


def test_one_quaternions_dcm_is_scipys_and_the_batchs_to_the_bit():
    """One (4,) quaternion goes through quat_to_dcm's Python-float path: scipy's matrix, and bit for bit the
    matrix the array path gives the same quaternion in a batch (the ins's heading checks read one at a time)."""
    q = rot.quat_normalize(np.random.default_rng(7).normal(size=(300, 4)))
    q[:4] = np.eye(4)                                  # ±0 products: signed zeros must match too
    batch = rot.quat_to_dcm(q)
    for qi, ci in zip(q, batch):
        one = rot.quat_to_dcm(qi)
        assert one.shape == (3, 3) and one.dtype == np.float64 and one.tobytes() == ci.tobytes()
    np.testing.assert_allclose(np.array([rot.quat_to_dcm(qi) for qi in q]), scipy_rot(q).as_matrix(), atol=1e-15)
    assert rot.quat_to_dcm([1, 0, 0, 0]).tobytes() == np.eye(3).tobytes()       # a list of ints, as before


def test_one_rotation_vectors_quaternion_is_the_batchs_to_the_bit():
    """One (3,) rotation vector goes through quat_exp's Python-float path: bit for bit what the array path gives
    the same vector in a batch, small angles (the series) and NaN included, and an infinite one still NaN."""
    rng = np.random.default_rng(11)
    v = np.concatenate((rng.normal(size=(300, 3)), 1e-3 * rng.normal(size=(300, 3)),
                        1e-8 * rng.normal(size=(100, 3)), [[0.0, 0.0, 0.0], [np.nan, 0.0, 0.0], [3.0, -2.0, 1.0]]))
    batch = rot.quat_exp(v)
    for vi, qi in zip(v, batch):
        one = rot.quat_exp(vi)
        assert one.shape == (4,) and one.dtype == np.float64 and one.tobytes() == qi.tobytes(), vi
    np.testing.assert_allclose(np.array([rot.quat_exp(vi) for vi in v[:600]]),
                               np.roll(Rotation.from_rotvec(v[:600]).as_quat(), 1, axis=1), atol=1e-14)
    with np.errstate(invalid="ignore"):
        assert np.all(np.isnan(rot.quat_exp([np.inf, 0.0, 0.0])[1:]))


def test_wrap():
    assert angles.wrap_pi(math.pi) == -math.pi
    assert math.isclose(angles.wrap_pi(3 * math.pi / 2), -math.pi / 2)
    assert angles.wrap_2pi(-1e-20) == 0.0
    assert math.isclose(angles.wrap_2pi(-math.pi / 2), 3 * math.pi / 2)
    w = angles.wrap_2pi(np.linspace(-20, 20, 1001))
    assert np.all((w >= 0) & (w < 2 * math.pi))


def test_dcm_to_quat_near_180_degrees():
    for axis in np.eye(3):
        c = rot.rotvec_to_dcm(axis * math.pi)
        assert rot.quat_angle_between(rot.dcm_to_quat(c), rot.quat_exp(axis * math.pi)) < 1e-12


def test_single_and_batch_dcm_to_quat_agree():
    q = rot.quat_normalize(np.random.default_rng(1).normal(size=(200, 4)))
    c = rot.quat_to_dcm(q)
    batch = rot.dcm_to_quat(c)
    single = np.array([rot.dcm_to_quat(ci) for ci in c])
    np.testing.assert_allclose(single, batch, atol=1e-15)
    # every Shepperd branch is exercised: pivots trace, C11, C22, C33
    pivots = np.argmax(np.stack([np.trace(c, axis1=1, axis2=2), c[:, 0, 0], c[:, 1, 1], c[:, 2, 2]], 1), 1)
    assert set(pivots) == {0, 1, 2, 3}


def test_vectorised_shapes_and_values():
    """(4, 5) batches give (4, 5, …) results, element by element what scipy gives for that quaternion."""
    q = rot.quat_normalize(np.random.default_rng(0).normal(size=(4, 5, 4)))
    ref = scipy_rot(q.reshape(-1, 4))                 # the same 20 rotations, flat
    dt = np.random.default_rng(1).uniform(0.001, 0.05, size=(4, 5))
    omega = np.array([0.3, -1.2, 2.0])
    dcm = rot.quat_to_dcm(q)
    assert dcm.shape == (4, 5, 3, 3)
    np.testing.assert_allclose(dcm.reshape(-1, 3, 3), ref.as_matrix(), atol=1e-14)
    back = rot.dcm_to_quat(dcm)
    assert back.shape == (4, 5, 4)
    np.testing.assert_allclose(np.abs(np.sum(back * q, axis=-1)), 1.0, atol=1e-14)    # ±q: the same rotation
    euler = rot.quat_to_euler(q)
    assert euler.shape == (4, 5, 3)
    np.testing.assert_allclose(euler.reshape(-1, 3)[:, ::-1], ref.as_euler("ZYX"), atol=1e-12)
    log = rot.quat_log(q)
    assert log.shape == (4, 5, 3)
    np.testing.assert_allclose(log.reshape(-1, 3), ref.as_rotvec(), atol=1e-12)
    q1 = rot.quat_integrate(q, omega, dt)
    assert q1.shape == (4, 5, 4)
    want = ref * Rotation.from_rotvec(omega[None, :] * dt.reshape(-1, 1))   # body rate: right-multiplied
    np.testing.assert_allclose(np.abs(np.sum(q1.reshape(-1, 4) * rot.quat_from_scalar_last(want.as_quat()), axis=-1)),
                               1.0, atol=1e-14)


# ------------------------------------------------------------------------------------------- properties
@PROPS
@given(unit_quats())
def test_quat_dcm_round_trip_and_scipy(q):
    c = rot.quat_to_dcm(q)
    np.testing.assert_allclose(c, scipy_rot(q).as_matrix(), atol=1e-14)
    assert rot.orthonormality_error(c) < 1e-14
    assert rot.quat_angle_between(rot.dcm_to_quat(c), q) < 1e-7
    back = rot.dcm_to_quat(c)
    assert back[0] >= 0.0
    assert min(np.abs(back - q).max(), np.abs(back + q).max()) < 1e-14


@PROPS
@given(st.floats(-math.pi, math.pi), st.floats(-1.55, 1.55), st.floats(-math.pi, math.pi))
def test_euler_round_trips(roll, pitch, yaw):
    q = rot.euler_to_quat(roll, pitch, yaw)
    assert math.isclose(np.linalg.norm(q), 1.0, abs_tol=1e-15)
    np.testing.assert_allclose(rot.quat_to_dcm(q), rot.euler_to_dcm(roll, pitch, yaw), atol=1e-14)
    for rpy in (rot.quat_to_euler(q), rot.dcm_to_euler(rot.euler_to_dcm(roll, pitch, yaw))):
        err = angles.wrap_pi(np.asarray(rpy) - [roll, pitch, yaw])
        np.testing.assert_allclose(err, 0.0, atol=1e-9 / math.cos(pitch))


@PROPS
@given(unit_quats())
def test_scalar_last_round_trip(q):
    s = rot.quat_to_scalar_last(q)
    np.testing.assert_array_equal(s, [q[1], q[2], q[3], q[0]])
    np.testing.assert_array_equal(rot.quat_from_scalar_last(s), q)


@PROPS
@given(rotvecs())
def test_exp_log_round_trip(v):
    q = rot.quat_exp(v)
    assert math.isclose(np.linalg.norm(q), 1.0, abs_tol=1e-15)
    np.testing.assert_allclose(rot.quat_log(q), v, atol=1e-12)
    np.testing.assert_allclose(rot.quat_to_dcm(q), Rotation.from_rotvec(v).as_matrix(), atol=1e-14)


@PROPS
@given(unit_quats(), unit_quats(), st.lists(finite, min_size=3, max_size=3))
def test_composition_is_matrix_product(p, q, v):
    pq = rot.quat_multiply(p, q)
    np.testing.assert_allclose(rot.quat_to_dcm(pq), rot.quat_to_dcm(p) @ rot.quat_to_dcm(q), atol=1e-14)
    np.testing.assert_allclose(rot.quat_rotate(pq, v), rot.quat_to_dcm(p) @ (rot.quat_to_dcm(q) @ v), atol=1e-14)
    np.testing.assert_allclose(rot.quat_multiply(q, rot.quat_conjugate(q)), [1, 0, 0, 0], atol=1e-15)
    np.testing.assert_allclose(rot.skew(p[1:]) @ q[1:], np.cross(p[1:], q[1:]), atol=1e-15)


@PROPS
@given(unit_quats(), rotvecs())
def test_angle_between(q, v):
    moved = rot.quat_multiply(q, rot.quat_exp(v))
    assert math.isclose(rot.quat_angle_between(q, moved), np.linalg.norm(v), abs_tol=1e-9)
    assert math.isclose(rot.dcm_angle_between(rot.quat_to_dcm(q), rot.quat_to_dcm(moved)),
                        np.linalg.norm(v), abs_tol=1e-7)


@PROPS
@given(unit_quats(), st.lists(st.floats(-0.15, 0.15), min_size=9, max_size=9))
def test_reorthonormalisation_converges(q, noise):
    truth = rot.quat_to_dcm(q)
    c = truth + np.reshape(noise, (3, 3))
    errors = [rot.orthonormality_error(rot.reorthonormalize(c, k)) for k in range(7)]
    assert errors[-1] < 1e-12
    assert errors[1] < errors[0] or errors[0] < 1e-15
    # It lands on the orthogonal polar factor (the nearest orthogonal matrix): U·Vᵀ of the SVD.
    u, _, vt = np.linalg.svd(c)
    np.testing.assert_allclose(rot.reorthonormalize(c, 8), u @ vt, atol=1e-10)


@PROPS
@given(unit_quats(), st.lists(st.floats(-0.2, 0.2), min_size=9, max_size=9))
def test_scalar_reorthonormalisation_matches_matrix_form(q, noise):
    c = rot.quat_to_dcm(q) + np.reshape(noise, (3, 3))
    np.testing.assert_allclose(np.array(rot.reorthonormalize_rows(c.tolist())), rot.reorthonormalize(c), atol=1e-14)


def test_reorthonormalisation_one_step_reduces_error_quadratically():
    c = rot.euler_to_dcm(0.1, 0.2, 0.3) * (1 + 1e-3)
    e0 = rot.orthonormality_error(c)
    e1 = rot.orthonormality_error(rot.reorthonormalize(c))
    assert e1 < 10 * e0**2


@pytest.mark.parametrize("n", [1, 7])
def test_integrate_constant_rate(n):
    q0 = rot.euler_to_quat(0.1, 0.2, 0.3)
    w = np.array([0.3, -0.2, 0.5])
    q = q0
    for _ in range(n):
        q = rot.quat_integrate(q, w, 1.0 / n)
    expected = (scipy_rot(q0) * Rotation.from_rotvec(w)).as_matrix()
    np.testing.assert_allclose(rot.quat_to_dcm(q), expected, atol=1e-14)



def test_skew_of_one_vector_is_the_batch_matrix_to_the_bit():
    """`skew` of one 3-vector (its Python-float path, per GNSS fix) is the matrix the batch path makes of it, bit
    for bit (signed zeros and NaN included), and its product is the cross product (numpy's, independent)."""
    vs = np.array([[0.3, -1.7, 2.5], [0.0, -0.0, 0.0], [-0.0, 4.0, math.nan], [1e-300, -1e300, math.inf]])
    batch = rot.skew(vs)
    for v, expected in zip(vs, batch, strict=True):
        one = rot.skew(v)
        assert one.shape == (3, 3) and one.dtype == np.float64
        assert one.tobytes() == expected.tobytes(), v
    b = np.array([0.2, 0.9, -0.4])
    np.testing.assert_allclose(rot.skew(vs[0]) @ b, np.cross(vs[0], b), rtol=1e-15, atol=1e-15)
