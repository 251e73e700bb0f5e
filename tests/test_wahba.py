"""Wahba solvers: exact recovery, agreement with the SVD optimum, the thesis methods' relationships to TRIAD, quality."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from ahrsd.estimator import wahba
from ahrsd.estimator.rotations import orthonormality_error, quat_angle_between, quat_from_scalar_last

PROPS = settings(derandomize=True, max_examples=40, deadline=None)
TWO_VECTOR_ONLY = {"thesis-v2", "triad-first", "triad-second"}  # use the first two vectors by definition
OPTIMAL = {"svd", "davenport", "quest"}


def random_case(seed: int, n: int, min_sin: float = 0.3):
    """A random rotation (scipy truth, body→reference) and n body unit vectors, the first two well separated."""
    rng = np.random.default_rng(seed)
    truth = Rotation.random(random_state=seed)
    while True:
        b = rng.normal(size=(n, 3))
        b /= np.linalg.norm(b, axis=1, keepdims=True)
        if np.linalg.norm(np.cross(b[0], b[1])) > min_sin:
            return truth, b, truth.apply(b), rng


@PROPS
@given(st.integers(0, 2**31), st.sampled_from(sorted(wahba.SOLVERS)), st.integers(2, 6))
def test_every_solver_recovers_a_rotation_exactly(seed, method, n):
    truth, b, r, rng = random_case(seed, n)
    r = r * rng.uniform(0.5, 60.0, size=(n, 1))  # vector lengths do not matter (units of g, µT)
    sol = wahba.solve(b, r, rng.uniform(0.1, 2.0, size=n), method=method)
    q_true = quat_from_scalar_last(truth.as_quat())
    assert quat_angle_between(sol.q_wxyz, q_true) < 1e-9
    assert sol.loss < 1e-18
    assert orthonormality_error(sol.dcm) < 1e-12 and np.linalg.det(sol.dcm) > 0
    assert sol.q_wxyz[0] >= 0 and math.isclose(np.linalg.norm(sol.q_wxyz), 1.0, abs_tol=1e-14)


@PROPS
@given(st.integers(0, 2**31), st.sampled_from(sorted(wahba.SOLVERS)), st.sampled_from([2, 3, 5]))
def test_noisy_solutions_agree_with_the_scipy_optimum(seed, method, n):
    sigma = 1e-3  # rad, direction noise per axis
    truth, b, r, rng = random_case(seed, n)
    noisy_b = b + rng.normal(scale=sigma, size=b.shape)
    noisy_r = r + rng.normal(scale=sigma, size=r.shape)
    w = np.full(n, 1.0 / sigma**2)
    # the optimum from scipy (Kabsch/SVD in Rotation.align_vectors), not from wahba: J = ½ Σ kᵢ ‖rᵢ − C bᵢ‖², Σk = 1
    unit_b = noisy_b / np.linalg.norm(noisy_b, axis=1, keepdims=True)
    unit_r = noisy_r / np.linalg.norm(noisy_r, axis=1, keepdims=True)
    optimum, _ = Rotation.align_vectors(unit_r, unit_b, weights=w)
    optimum_loss = 0.5 * np.sum(w / w.sum() * np.sum((unit_r - optimum.apply(unit_b)) ** 2, axis=1))
    ref = SimpleNamespace(q_wxyz=quat_from_scalar_last(optimum.as_quat()), loss=optimum_loss)
    sol = wahba.solve(noisy_b, noisy_r, w, method=method)
    angle = quat_angle_between(sol.q_wxyz, ref.q_wxyz)
    if method in OPTIMAL:
        assert angle < 1e-8
        assert math.isclose(sol.loss, ref.loss, rel_tol=1e-6, abs_tol=1e-15)
    else:
        # Sub-optimal methods: within a few σ, amplified by 1/sin of the angle between the first two vectors
        # (≥ 0.3 here) and by the √N information they throw away.
        conditioning = np.linalg.norm(np.cross(b[0], b[1]))
        if method == "three-vector" and n > 2:  # inverts the stacked vectors: noise grows with 1/s_min
            conditioning = min(conditioning, np.linalg.svd(r, compute_uv=False)[-1])
        assert angle < 12 * sigma * math.sqrt(n) / conditioning
    assert sol.loss >= ref.loss - 1e-15  # the optimum is the global minimum of J


@PROPS
@given(st.integers(0, 2**31))
def test_thesis_v2_reorthonormalised_is_triad_anchored_on_the_first_vector(seed):
    truth, b, r, rng = random_case(seed, 2)
    noisy_b = b + rng.normal(scale=0.01, size=b.shape)
    v2 = wahba.thesis_v2(noisy_b, r)
    triad = wahba.triad_first(noisy_b, r)
    assert quat_angle_between(v2.q_wxyz, triad.q_wxyz) < 1e-9
    # ... and the anchor is matched exactly in both.
    np.testing.assert_allclose(triad.dcm @ (noisy_b[0] / np.linalg.norm(noisy_b[0])), r[0], atol=1e-12)
    second = wahba.triad_second(noisy_b, r)
    np.testing.assert_allclose(second.dcm @ (noisy_b[1] / np.linalg.norm(noisy_b[1])), r[1], atol=1e-12)


def test_thesis_version_1_reference_matrix_closed_form():
    # N_n = [mⁿ, fⁿ, fⁿ×mⁿ] with mⁿ = [hn, he, hd], fⁿ = [0, 0, −g]: N_n^{-T} is the printed matrix.
    hn, he, hd, g = 21.3, 1.9, 44.7, 9.80665
    n_matrix = wahba.thesis_matrix([hn, he, hd], [0.0, 0.0, -g], 1)
    np.testing.assert_allclose(n_matrix[:, 2], [g * he, -g * hn, 0.0])  # third column fⁿ×mⁿ
    h2 = hn**2 + he**2
    printed = np.array([
        [hn / h2, hn * hd / (g * h2), he / (g * h2)],
        [he / h2, hd * he / (g * h2), -hn / (g * h2)],
        [0.0, -1.0 / g, 0.0],
    ])
    np.testing.assert_allclose(np.linalg.inv(n_matrix).T, printed, rtol=1e-13, atol=1e-16)
    # And C_b^n = N^{-T} Bᵀ recovers a rotation from the raw (un-normalised) body vectors.
    truth = Rotation.from_euler("ZYX", [1.1, 0.2, -0.3]).as_matrix()
    mb, fb = truth.T @ [hn, he, hd], truth.T @ [0.0, 0.0, -g]
    c = printed @ np.vstack((mb, fb, np.cross(fb, mb)))
    np.testing.assert_allclose(c, truth, atol=1e-13)


def test_three_vector_is_w_v_inverse_for_three_vectors():
    truth, b, r, rng = random_case(7, 3)
    noisy_b = b + rng.normal(scale=0.02, size=b.shape)
    sol = wahba.three_vector(noisy_b, r)
    unit_b = noisy_b / np.linalg.norm(noisy_b, axis=1, keepdims=True)
    c_nb = unit_b.T @ np.linalg.inv(r.T)  # C_n^b = B N⁻¹ with vectors as columns
    np.testing.assert_allclose(sol.dcm_raw, c_nb.T, atol=1e-12)
    assert orthonormality_error(sol.dcm_raw) > 1e-3  # noisy data: the raw inversion is not a rotation ...
    assert orthonormality_error(sol.dcm) < 1e-12     # ... until C ← 1.5C − 0.5CCᵀC is applied


def test_version_1_raw_dcm_is_not_orthonormal_and_reorthonormalisation_fixes_it():
    truth, b, r, rng = random_case(11, 2)
    sol = wahba.three_vector(b + rng.normal(scale=0.01, size=b.shape), r)
    assert orthonormality_error(sol.dcm_raw) > 1e-3
    assert orthonormality_error(sol.dcm) < 1e-12
    assert quat_angle_between(sol.q_wxyz, quat_from_scalar_last(truth.as_quat())) < 0.1


def test_covariance_two_orthogonal_vectors_analytic():
    sigma = 0.01
    b = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    sol = wahba.svd(b, b, np.full(2, 1 / sigma**2))
    np.testing.assert_allclose(sol.covariance, np.diag([sigma**2, sigma**2, sigma**2 / 2]), rtol=1e-10)


def test_covariance_matches_monte_carlo_scatter():
    sigma = 2e-3
    truth, b, r, rng = random_case(3, 3)
    q_true = quat_from_scalar_last(truth.as_quat())
    errors = []
    for _ in range(400):
        sol = wahba.svd(b + rng.normal(scale=sigma, size=b.shape), r, np.full(3, 1 / sigma**2))
        d = Rotation.from_quat(np.roll(sol.q_wxyz, -1)) * Rotation.from_quat(np.roll(q_true, -1)).inv()
        errors.append(d.as_rotvec())
    errors = np.array(errors)
    predicted = np.trace(sol.covariance)
    measured = np.mean(np.sum(errors**2, axis=1))
    assert 0.8 < measured / predicted < 1.25


def test_loss_for_known_residual():
    # Second vector tilted by a towards the anchor (TRIAD keeps C = I): J = ½·½·(2 sin(a/2))², equal weights.
    a = 0.1
    b = np.array([[1.0, 0, 0], [0, 0, 1.0]])
    r = np.array([[1.0, 0, 0], [math.sin(a), 0, math.cos(a)]])
    sol = wahba.triad_first(b, r)
    assert math.isclose(sol.loss, 0.25 * (2 * math.sin(a / 2)) ** 2, rel_tol=1e-12)


@pytest.mark.parametrize("axis", [[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [1.0, 1.0, 0]])
@pytest.mark.parametrize("method", sorted(wahba.SOLVERS))
def test_180_degree_rotations(axis, method):
    truth = Rotation.from_rotvec(np.array(axis) / np.linalg.norm(axis) * math.pi)
    b = np.array([[0.3, -0.5, 0.8], [0.9, 0.1, -0.2], [0.1, 0.9, 0.3]])
    sol = wahba.solve(b, truth.apply(b), method=method)
    assert quat_angle_between(sol.q_wxyz, quat_from_scalar_last(truth.as_quat())) < 1e-9


def test_registry_and_aliases():
    assert set(wahba.SOLVERS) == {"three-vector", "thesis-v2", "triad-first", "triad-second", "svd", "davenport", "quest"}
    assert wahba.get_solver("thesis-v1") is wahba.three_vector
    assert wahba.get_solver("triad") is wahba.triad_first
    with pytest.raises(ValueError, match="unknown Wahba method"):
        wahba.get_solver("foo")


@pytest.mark.parametrize("method", sorted(wahba.SOLVERS))
def test_bad_input_is_rejected(method):
    good = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    for body, ref, w in [
        (good[:1], good[:1], None),                       # one vector: rotation about it unobservable
        (good, good[:, :2], None),                        # wrong shape
        (np.array([[1.0, 0, 0], [2.0, 0, 0]]), good, None),  # collinear body vectors
        (np.array([[np.nan, 0, 0], [0, 1.0, 0]]), good, None),
        (np.array([[0.0, 0, 0], [0, 1.0, 0]]), good, None),
        (good, good, [1.0, -1.0]),
        (good, good, [1.0]),
    ]:
        with pytest.raises(wahba.WahbaError):
            wahba.solve(body, ref, w, method=method)
