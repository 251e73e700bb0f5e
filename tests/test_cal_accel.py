"""Multi-position accelerometer calibration (calibration/inertial/accel.py).

Simulated positions: the simulator's static scenario (ADIS16405 noise) held for 10 s at 50 Hz in each
orientation. The mean of one position then carries white noise VRW/√T = 3.3e-3/√10 = 1.05e-3 m/s² and the
in-run bias (Gauss–Markov σ 0.2 mg = 1.96e-3 m/s², independent between positions here), so
σ_pos ≈ 2.2e-3 m/s². With 26 positions spread over the sphere each bias is determined to about σ_pos/2 and
each matrix entry to about σ_pos/(2g). Tolerances: TOL_BIAS = 5e-3 m/s² and TOL_MATRIX = 1e-3 (≥ 4σ).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ahrsd.calibration.inertial.accel import (
    GUIDED_TARGETS,
    GuidedSession,
    find_still_segments,
    fit_accel,
    local_gravity_m_s2,
    model_from_linear,
    regressors,
)
from ahrsd.core.sample import make_sample
from ahrsd.simulation import DEFAULT_SITE, SensorErrors, simulate
from ahrsd.simulation.scenarios import Static

from support.accel_positions import roll_pitch_for_up, up_vectors
from support.gravity_worked_values import GRAVITY_WORKED_VALUES

G = DEFAULT_SITE.gravity_m_s2
TOL_BIAS = 5e-3
TOL_MATRIX = 1e-3
MG = 1e-3 * 9.80665


def simulated_positions(errs: SensorErrors, seconds=10.0, rate_hz=50.0) -> np.ndarray:
    means = []
    for k, u in enumerate(up_vectors()):
        roll, pitch = roll_pitch_for_up(u)
        block = simulate(Static(heading_deg=30.0 * k, roll_deg=roll, pitch_deg=pitch), seconds, rate_hz=rate_hz,
                         seed=100 + k, errors=errs)
        means.append(block.accel_m_s2.mean(axis=0))
    return np.array(means)


def gram(m):
    """MᵀM: what the gravity norm can see of a calibration matrix (a rotation of M is invisible)."""
    return m.T @ m


def test_roll_pitch_helper_puts_gravity_where_asked():
    for u in up_vectors(5):
        roll, pitch = roll_pitch_for_up(u)
        block = simulate(Static(roll_deg=roll, pitch_deg=pitch), 0.1, rate_hz=10, errors="ideal")
        np.testing.assert_allclose(block.accel_m_s2[0] / np.linalg.norm(block.accel_m_s2[0]), u, atol=1e-9)


# ---------------------------------------------------------------------------------------------- thesis algebra


@settings(derandomize=True, max_examples=60, deadline=None)
@given(st.lists(st.floats(-2e-3, 2e-3), min_size=12, max_size=12))
def test_regressor_rows_are_the_first_order_expansion_of_the_norm(x):
    """The linear step: (g − |S_o|)·g = h·X_a up to second order in the errors, for |S^P| = g."""
    x_a = np.array(x) * np.array([1, 1, 1, 50, 50, 50, 1, 1, 1, 1e-3, 1e-3, 1e-3])
    model = model_from_linear(x_a)
    rng = np.random.default_rng(0)
    u = rng.normal(size=(40, 3))
    f_true = G * u / np.linalg.norm(u, axis=1, keepdims=True)
    # Invert S^P = (I+E)·S_o + δS_b + K_nl·S_o² for S_o by fixed-point iteration (errors are small).
    a_yx, a_xy, a_xz, bx, by, bz, kx, ky, kz, nx, ny, nz = x_a
    e = np.array([[-kx, 0, 0], [a_xz, -ky, 0], [-a_xy, a_yx, -kz]])
    s_o = f_true.copy()
    for _ in range(50):
        s_o = f_true - (s_o @ e.T + np.array([bx, by, bz]) + np.array([nx, ny, nz]) * s_o**2)
    z, h = regressors(s_o, G)
    err_scale = np.max(np.abs(x_a / np.array([1, 1, 1, G, G, G, 1, 1, 1, 1 / G, 1 / G, 1 / G])))
    np.testing.assert_allclose(h @ x_a, z, atol=G * G * (4 * err_scale**2 + 1e-12))
    # And the model built from X_a maps S_o back to |f| ≈ g to first order.
    np.testing.assert_allclose(np.linalg.norm(model.apply(s_o), axis=1), G, atol=G * 6 * err_scale**2 + 1e-9)


def test_noise_free_recovery_of_all_12_parameters_including_quadratic():
    rng = np.random.default_rng(4)
    lower = np.array([[1.03, 0, 0], [0.004, 0.97, 0], [-0.002, 0.006, 1.01]])
    bias = np.array([0.15, -0.08, 0.2])
    quad = np.array([2e-4, -1e-4, 3e-4])
    u = up_vectors(10)
    f_true = G * u
    # Raw from the model f = L·(raw − b − q∘raw²): solve per axis (quadratic in raw) by iteration.
    target = np.linalg.solve(lower, f_true.T).T + bias
    raw = target.copy()
    for _ in range(60):
        raw = target + quad * raw * raw
    res = fit_accel(raw, G, terms=12)
    assert res.ok and res.terms == 12
    np.testing.assert_allclose(res.model.bias_m_s2, bias, atol=1e-9)
    np.testing.assert_allclose(res.model.matrix, lower, atol=1e-10)
    np.testing.assert_allclose(res.model.quadratic, quad, atol=1e-10)
    assert res.residual_rms_m_s2 < 1e-9
    # The thesis's linear step alone is only first-order accurate (a few mm/s² here).
    assert np.max(np.abs(res.linear_model.bias_m_s2 - bias)) < 0.02


# ---------------------------------------------------------------------------------------------- recovery


def test_simulated_adis16405_positions_are_recovered():
    errs = SensorErrors.adis16405(seed=9)
    res = fit_accel(simulated_positions(errs), G, terms=9)
    assert res.ok, res.refused
    np.testing.assert_allclose(res.model.bias_m_s2, errs.accel_bias_m_s2, atol=TOL_BIAS)
    truth = np.linalg.inv(errs.accel_matrix)
    np.testing.assert_allclose(gram(res.model.matrix), gram(truth), atol=2 * TOL_MATRIX)


def test_thesis_accel_calibration_figures_as_truth_are_recovered():
    """Worked example, the thesis's accelerometer calibration result: bias −17.5, −24.68, −18.57 mg; gains 0.92, 1.04, 0.98; the
    speculative misalignments α_xy = −0.0002, α_xz = −0.0005, α_yx = −0.0052 rad. Injected as
    raw = diag(gain)·T⁻¹·f + b (T the thesis's lower-triangular T_a^P) and fitted with all 12 terms."""
    bias = np.array([-17.5, -24.68, -18.57]) * MG
    gain = np.array([0.92, 1.04, 0.98])
    t = np.array([[1, 0, 0], [-0.0005, 1, 0], [0.0002, -0.0052, 1]])  # [[1,0,0],[α_xz,1,0],[−α_xy,α_yx,1]]
    a = np.diag(gain) @ np.linalg.inv(t)
    errs = SensorErrors.adis16405(seed=1).replace(
        accel_bias_m_s2=bias, accel_scale=np.diag(a) - 1, accel_misalignment_rad=a - np.diag(np.diag(a)))
    res = fit_accel(simulated_positions(errs), G, terms=12)
    assert res.ok, res.refused
    # The quadratic terms (zero here) absorb some noise, so allow twice the 9-term tolerances.
    np.testing.assert_allclose(res.model.bias_m_s2, bias, atol=2 * TOL_BIAS)
    truth = np.linalg.inv(a)
    np.testing.assert_allclose(gram(res.model.matrix), gram(truth), atol=4 * TOL_MATRIX)
    # Scale factors to 0.1 %: the thesis's accelerometer gains are recovered.
    np.testing.assert_allclose(1 / np.sqrt(np.diag(gram(res.model.matrix))), 1 / np.sqrt(np.diag(gram(truth))),
                               atol=2e-3)


# ---------------------------------------------------------------------------------------------- refusals


def test_too_few_orientations_are_refused_and_auto_picks_what_they_support():
    u = up_vectors()[:6]  # the six faces only
    res = fit_accel(G * u + 0.01, G, terms=12)
    assert not res.ok and "6 distinct orientations cannot determine 12" in res.refused
    res = fit_accel(G * u + 0.01, G)  # auto → 6 terms
    assert res.ok and res.terms == 6
    np.testing.assert_allclose(res.model.bias_m_s2, 0.01, atol=1e-9)
    res = fit_accel(G * np.tile(u[:1], (20, 1)), G)
    assert not res.ok and "1 distinct" in res.refused


def test_a_position_taken_while_moving_is_refused():
    u = up_vectors()
    raw = G * u
    raw[3] *= 1.05  # someone bumped the table
    res = fit_accel(raw, G)
    assert not res.ok and "residual" in res.refused and "position 4 of 26" in res.refused


def somigliana_m_s2(lat_deg: float, alt_m: float) -> float:
    """WGS-84 normal gravity, Somigliana's closed form, with the free-air gradient for height (NIMA TR8350.2
    eq. 4-1 and 4-3, second-order height term dropped)."""
    ge, k, e2 = 9.7803253359, 0.00193185265241, 0.00669437999013
    s2 = math.sin(math.radians(lat_deg)) ** 2
    g0 = ge * (1 + k * s2) / math.sqrt(1 - e2 * s2)
    return g0 - 3.086e-6 * alt_m


@pytest.mark.parametrize("lat, g0, g1000", GRAVITY_WORKED_VALUES)
def test_local_gravity_matches_the_worked_values(lat, g0, g1000):
    assert local_gravity_m_s2(lat, 0.0) == pytest.approx(g0, abs=1.5e-6)
    assert local_gravity_m_s2(lat, 1000.0) == pytest.approx(g1000, abs=1.5e-6)


@pytest.mark.parametrize("lat, alt", [(0.0, 0.0), (36.42, 1345.0), (-52.0, 300.0), (78.0, 3000.0)])
def test_local_gravity_agrees_with_somigliana(lat, alt):
    # eq. 18 is a series of the closed form (2e-6 m/s² apart at sea level); its spherical (R0/(R0+h))² height
    # factor and the free-air gradient differ by up to 2e-5 m/s² at these heights
    assert local_gravity_m_s2(lat, alt) == pytest.approx(somigliana_m_s2(lat, alt), abs=3e-5)


def test_local_gravity_without_a_latitude_is_standard_gravity():
    assert local_gravity_m_s2(None) == 9.80665


# ---------------------------------------------------------------------------------------------- recordings


def test_still_periods_of_a_rate_table_recording_are_found():
    rate = 50.0
    block = simulate("rate-table", 400, rate_hz=rate, seed=2)
    segs = find_still_segments(block.accel_m_s2, block.gyro_rad_s, rate, min_still_s=3.0)
    assert len(segs) >= 12
    for s in segs:
        # Really still in the truth: turned less than 0.01° during the segment (at most the first 0.1 s of a
        # raised-cosine ramp about the vertical, far below the gyro noise and invisible to the accelerometer).
        turned_rad = np.sum(np.linalg.norm(block.truth_gyro_rad_s[s.start:s.stop], axis=1)) / rate
        assert turned_rad < math.radians(0.01)
        assert np.linalg.norm(s.mean_accel_m_s2) == pytest.approx(G, rel=0.02)
    ups = {tuple(np.round(s.mean_accel_m_s2 / G).astype(int)) for s in segs}
    assert len(ups) == 6  # every axis up and down


# ---------------------------------------------------------------------------------------------- guided


class FakeOperator:
    """Turns a simulated unit into whatever position the session asks for, with ADIS16405-like noise."""

    def __init__(self, rate_hz: float, bias, matrix):
        self.rate, self.bias, self.a = rate_hz, np.asarray(bias), np.asarray(matrix)
        self.rng = np.random.default_rng(7)
        self.t = 0.0

    def samples(self, up, seconds, moving=False):
        for _ in range(int(seconds * self.rate)):
            self.t += 1 / self.rate
            f = G * np.asarray(up) / np.linalg.norm(up)
            raw = self.a @ f + self.bias + self.rng.normal(0, 0.095 / math.sqrt(819.2 / self.rate), 3)
            gyro = self.rng.normal(0, 0.01, 3) + (0.8 if moving else 0.0)
            if moving:
                raw = raw + self.rng.normal(0, 2.0, 3)
            yield make_sample(self.t, gyro, raw, [20.0, 0.0, 40.0])


def test_guided_session_prompts_detects_stillness_records_and_fits():
    rate = 50.0
    bias = np.array([0.05, -0.08, 0.12])
    a = np.array([[1.01, 0.002, -0.001], [0.0, 0.99, 0.003], [0.001, -0.002, 1.02]])
    op = FakeOperator(rate, bias, a)
    session = GuidedSession(rate_hz=rate, still_s=3.0)
    messages = []
    assert session.prompt.startswith("position 1/14")
    # The operator first holds the unit in a wrong, in-between position: it is not recorded.
    for s in op.samples([1.0, 1.0, 0.2], 4.0):
        msg = session.feed(s)
        messages.append(msg) if msg else None
    assert any("not in any of the requested positions" in m for m in messages) and not session.recorded
    for _ in range(40):
        if session.done:
            break
        target = next(i for i in range(len(session.targets)) if i not in session.recorded)
        for s in op.samples(session.targets[target][1], 0.5, moving=True):  # turning it over
            session.feed(s)
        for s in op.samples(session.targets[target][1], 3.5):
            msg = session.feed(s)
            if msg:
                messages.append(msg)
    assert session.done and len(session.recorded) == 14
    assert any(m.startswith("recorded") for m in messages)
    assert "faces" in session.coverage()
    res = session.fit(G)
    assert res.ok and res.terms == 12
    np.testing.assert_allclose(res.model.bias_m_s2, bias, atol=5e-3)
    np.testing.assert_allclose(gram(res.model.matrix), gram(np.linalg.inv(a)), atol=2e-3)


def test_guided_face_pairs_take_a_second_hold_of_each_face_only_after_the_unit_moved():
    """`--live --align-to-faces`: each face is asked for twice (turned half round between); a hold that
    continues the one just recorded does not count as the second."""
    from ahrsd.calibration.inertial.accel import GUIDED_TARGETS_FACE_PAIRS

    rate = 50.0
    op = FakeOperator(rate, np.zeros(3), np.eye(3))
    session = GuidedSession(rate_hz=rate, still_s=3.0, targets=GUIDED_TARGETS_FACE_PAIRS)
    assert session.prompt.startswith("position 1/20")
    face = session.targets[0][1]
    for s in op.samples(face, 10.0):           # one long hold: three still periods' worth, never moved
        session.feed(s)
    assert sorted(session.recorded) == [0]
    assert "again, turned half round" in session.prompt
    for s in op.samples(face, 0.5, moving=True):
        session.feed(s)
    messages = [m for s in op.samples(face, 3.5) if (m := session.feed(s))]
    assert sorted(session.recorded) == [0, 1] and messages[0].startswith("recorded") and "half round" in messages[0]
    for s in op.samples(face, 0.5, moving=True):
        session.feed(s)
    messages = [m for s in op.samples(face, 3.5) if (m := session.feed(s))]
    assert sorted(session.recorded) == [0, 1] and messages[0].startswith("already have")


@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_guided_session_skips_a_non_finite_sample_as_if_it_never_came(bad):
    """A sample with a NaN or infinite value (an invalid read) is dropped before the still-period blocks: the
    position is recorded with the same mean, at the same sample, as without it."""
    rate = 50.0
    held = list(FakeOperator(rate, np.zeros(3), np.eye(3)).samples(GUIDED_TARGETS[0][1], 4.0))
    clean, damaged = GuidedSession(rate_hz=rate, still_s=3.0), GuidedSession(rate_hz=rate, still_s=3.0)
    clean_msgs = [clean.feed(s) for s in held]
    damaged_msgs = []
    for k, s in enumerate(held):
        if k in (20, 61):
            accel = np.array(s.accel_m_s2)
            accel[k % 3] = bad
            assert damaged.feed(s.with_values(accel_m_s2=accel)) is None
            assert damaged.feed(s.with_values(gyro_rad_s=np.array([0.0, bad, 0.0]))) is None
        damaged_msgs.append(damaged.feed(s))
    assert clean_msgs == damaged_msgs and sorted(clean.recorded) == [0]
    assert np.array_equal(clean.recorded[0], damaged.recorded[0])
