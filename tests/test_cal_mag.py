"""Magnetometer calibrations: two-step, three-step, alignment, ellipsoid, and the fit_mag dispatch.

Data: the simulator (ahrsd.simulation) at 20 Hz, so the per-sample magnetometer noise is the ADIS16405's
0.125 µT rms at 819.2 SPS scaled by √(20/819.2): σ_m = 0.0195 µT. A fit of p parameters to n samples
spread over the sphere determines the hard iron to about σ_m·√(3/n) and each soft-iron entry to about
σ_m/|F|·√(3/n) (each axis sees a third of the information). Tolerances are 6× those (names TOL_*),
computed from n in each test.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ahrsd.calibration.mag import three_step, two_step
from ahrsd.calibration.mag.fit_types import MagFitInput, MagFitResult
from ahrsd.calibration.mag.fit import METHODS, fit_mag
from ahrsd.calibration.mag.alignment import LevelTurn, fit_alignment, orthogonalise, segment_level_turns
from ahrsd.calibration.models import MagModel, misalignment_matrix
from ahrsd.simulation import DEFAULT_SITE, SensorErrors, simulate

RATE_HZ = 20.0
REF = DEFAULT_SITE.earth_field()
SIGMA_M_UT = 0.125 * math.sqrt(RATE_HZ / 819.2)   # ADIS16405 mag noise 1.25 mgauss rms at 819.2 SPS (simulator)


def tolerances(n: int) -> tuple[float, float]:
    """(hard iron µT, soft-iron entry) 6σ tolerances for n samples over the sphere."""
    k = 6.0 * math.sqrt(3.0 / n)
    return k * SIGMA_M_UT, k * SIGMA_M_UT / REF.total_ut


def errors_with(hard_ut, soft) -> SensorErrors:
    return SensorErrors.adis16405(seed=2).replace(hard_iron_ut=np.asarray(hard_ut, float), soft_iron=np.asarray(soft, float))


def tumble(errs: SensorErrors, seconds=150.0, seed=1):
    return simulate("tumble", seconds, rate_hz=RATE_HZ, seed=seed, errors=errs, vehicle_iron=None)


def as_input(block) -> MagFitInput:
    return MagFitInput(block.t_s, block.mag_ut, block.accel_m_s2, block.gyro_rad_s)


# ---------------------------------------------------------------------------------------------- thesis algebra

POS = st.floats(0.6, 1.5)
BIAS = st.floats(-60.0, 60.0)
SMALL = st.floats(-0.08, 0.08)


@settings(derandomize=True, max_examples=80, deadline=None)
@given(BIAS, BIAS, BIAS, POS, POS, POS, st.floats(20.0, 65.0))
def test_two_step_inverse_mapping(bx, by, bz, kx, ky, kz, h0):
    """S(b, k, H0) of the two-step regression mapped back by inverse_mapping gives b and k."""
    s = two_step.forward_mapping(np.array([bx, by, bz]), np.array([kx, ky, kz]), h0)
    b, k = two_step.inverse_mapping(s, h0)
    np.testing.assert_allclose(b, [bx, by, bz], atol=1e-9 * (1 + abs(bx) + abs(by) + abs(bz)))
    np.testing.assert_allclose(k, [kx, ky, kz], rtol=1e-8)


def test_two_step_regression_rows_are_the_linearised_ellipsoid():
    rng = np.random.default_rng(0)
    b, k, h0 = np.array([10.0, -5.0, 3.0]), np.array([1.1, 0.9, 1.05]), 48.0
    u = rng.normal(size=(50, 3))
    raw = b + k * (h0 * u / np.linalg.norm(u, axis=1, keepdims=True))
    z, h = two_step.regressors(raw)
    np.testing.assert_allclose(h @ two_step.forward_mapping(b, k, h0), z, rtol=1e-9, atol=1e-7)


@settings(derandomize=True, max_examples=80, deadline=None)
@given(BIAS, BIAS, BIAS, POS, POS, POS, SMALL, SMALL, SMALL, st.floats(20.0, 65.0))
def test_three_step_chain_x_to_s_gamma_to_b_k_alpha(bx, by, bz, kx, ky, kz, a_yz, a_zy, a_zx, h0):
    """(b, k, α) → (b′, γ, S) → X, and the corrected inverse relations take X back to (b, k, α)."""
    b, k = np.array([bx, by, bz]), np.array([kx, ky, kz])
    g_yz, g_zy, g_zx = kx / ky * a_yz, kx / kz * a_zy, ky / kz * a_zx
    bp = np.array([bx - g_yz * by + g_zy * bz, by - g_zx * bz, bz])
    s = two_step.forward_mapping(bp, k, h0)  # S has the two-step form with b′
    x = three_step.x_from_s_gamma(s, g_yz, g_zy, g_zx)
    s_back, gamma = three_step.s_gamma_from_x(x)
    np.testing.assert_allclose(s_back, s, rtol=1e-9, atol=1e-9 * (1 + np.abs(s).max()))
    assert (gamma["yz"], gamma["zy"], gamma["zx"]) == pytest.approx((g_yz, g_zy, g_zx), abs=1e-10)
    bp_back, b_back, k_back, alpha = three_step.b_k_alpha_from_s_gamma(s_back, gamma, h0)
    np.testing.assert_allclose(bp_back, bp, atol=1e-7)
    np.testing.assert_allclose(b_back, b, atol=1e-7)
    np.testing.assert_allclose(k_back, k, rtol=1e-8)
    assert (alpha["yz"], alpha["zy"], alpha["zx"]) == pytest.approx((a_yz, a_zy, a_zx), abs=1e-9)


def test_three_step_regression_is_exact_on_its_own_model():
    """Noise-free data from B = b + K·T⁻¹·H (the thesis's model, upper-triangular T): the raw algorithm is exact."""
    rng = np.random.default_rng(5)
    b, k, alpha = np.array([12.0, -7.0, 30.0]), np.array([0.95, 1.08, 1.02]), {"yz": 0.02, "zy": -0.03, "zx": 0.015}
    u = rng.normal(size=(300, 3))
    h = REF.total_ut * u / np.linalg.norm(u, axis=1, keepdims=True)
    raw = b + (np.diag(k) @ np.linalg.inv(misalignment_matrix(alpha)) @ h.T).T
    p = three_step.solve(raw, REF.total_ut)
    np.testing.assert_allclose(p.b, b, atol=1e-6)
    np.testing.assert_allclose(p.k, k, rtol=1e-9)
    for key in alpha:
        assert p.alpha[key] == pytest.approx(alpha[key], abs=1e-9)


# ---------------------------------------------------------------------------------------------- recovery


def test_two_step_recovers_hard_iron_and_scale_on_simulated_tumble():
    hard, scale = np.array([25.0, -12.0, 8.0]), np.array([1.07, 0.93, 1.02])
    block = tumble(errors_with(hard, np.diag(scale)))
    res = fit_mag("two-step", as_input(block), REF)
    assert res.ok, res.refused
    tol_h, tol_s = tolerances(len(block))
    np.testing.assert_allclose(res.model.hard_iron_ut, hard, atol=tol_h)
    np.testing.assert_allclose(res.model.soft_iron, np.diag(1 / scale), atol=tol_s)
    assert res.residual_rms_ut == pytest.approx(SIGMA_M_UT, rel=0.2)
    assert res.quality["coverage"] == 1.0


@pytest.mark.parametrize("method", ["three-step", "ellipsoid"])
def test_full_fits_recover_a_non_symmetric_soft_iron_up_to_rotation(method):
    """The simulator's default vehicle iron (non-symmetric soft iron) plus the sensor's own errors: the
    magnitude fixes the hard iron and SᵀS (a rotation of S is invisible to it)."""
    from ahrsd.simulation import VehicleIron

    errs = SensorErrors.adis16405(seed=4).with_vehicle_iron(VehicleIron.default())
    block = tumble(errs)
    res = fit_mag(method, as_input(block), REF)
    assert res.ok, res.refused
    truth = np.linalg.inv(errs.soft_iron)
    tol_h, tol_s = tolerances(len(block))
    np.testing.assert_allclose(res.model.hard_iron_ut, errs.hard_iron_ut, atol=tol_h)
    np.testing.assert_allclose(res.model.soft_iron.T @ res.model.soft_iron, truth.T @ truth, atol=2 * tol_s)
    assert res.residual_rms_ut < 1.3 * SIGMA_M_UT


def test_thesis_mag_calibration_figures_as_truth_three_step_plus_alignment_recovers_everything():
    """Worked example, the thesis's magnetometer calibration result (one reading of its misalignments): b = 75.7678, −5.02, −28.39 mG,
    k = 0.91, 0.9069, 0.9334, six α. Three-step on a tumble, then the alignment step on levelled turns
    about each axis (the simulated rate table), recover the full soft iron T·K⁻¹ including its rotation."""
    b = np.array([75.7678, -5.02, -28.39]) * 0.1            # mG → µT
    k = np.array([0.91, 0.9069, 0.9334])
    alpha = {"xy": 0.0055, "xz": 0.0052, "yx": -0.0555, "yz": -0.0202, "zx": 0.0022, "zy": -0.0002}
    truth = MagModel.from_thesis(b, k, alpha)                 # calibrated = T·K⁻¹·(B − b)
    errs = errors_with(b, np.linalg.inv(truth.soft_iron))     # measured = K·T⁻¹·H + b
    three = fit_mag("three-step", as_input(tumble(errs)), REF)
    assert three.ok, three.refused
    table = simulate("rate-table", 420, rate_hz=RATE_HZ, seed=3, errors=errs.replace(
        accel_bias_m_s2=np.zeros(3), accel_misalignment_rad=np.zeros((3, 3))))
    turns = segment_level_turns(table.gyro_rad_s, table.accel_m_s2, table.mag_ut, RATE_HZ)
    assert {t.axis for t in turns} == {"x", "y", "z"}
    al = fit_alignment(turns, three.model, REF.down_ut)
    assert al.ok, al.refused
    aligned = fit_mag("three-step", as_input(tumble(errs)), REF, alignment=al.rotation)
    tol_h, tol_s = tolerances(len(tumble(errs)))
    np.testing.assert_allclose(aligned.model.hard_iron_ut, b, atol=tol_h)
    # The alignment rows come from ~5000 samples per axis with the same noise, but also carry the
    # turn's residual tilt (simulated table: level to the accelerometer); 1e-3 rad covers both.
    np.testing.assert_allclose(aligned.model.soft_iron, truth.soft_iron, atol=1e-3)
    params = aligned.model.to_thesis()
    # α_xz, α_xy, α_yx are the rotation part: after alignment the model equals T·K⁻¹ as a whole.
    np.testing.assert_allclose(MagModel.from_thesis(params.bias_ut, params.scale, params.alpha,
                                                    params.alignment).soft_iron, aligned.model.soft_iron, atol=1e-12)


def test_alignment_orthogonalisation_methods():
    from scipy.spatial.transform import Rotation

    r = Rotation.from_rotvec([0.02, -0.05, 0.03]).as_matrix()
    noisy = r + np.random.default_rng(1).normal(0, 1e-3, (3, 3))
    for method in ("svd", "cholesky"):
        q = orthogonalise(noisy, method)
        np.testing.assert_allclose(q @ q.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(q) == pytest.approx(1.0)
        np.testing.assert_allclose(q, r, atol=5e-3)
    with pytest.raises(ValueError):
        orthogonalise(noisy, "gram")


def test_alignment_refuses_tilted_or_short_turns():
    rng = np.random.default_rng(0)
    ang = np.linspace(0, math.pi / 4, 100)  # only 45° of turn
    h = np.column_stack([REF.horizontal_ut * np.cos(ang), REF.horizontal_ut * np.sin(ang), np.full(100, REF.down_ut)])
    acc = np.tile([0.0, 0.0, -9.8], (100, 1))
    short = LevelTurn("z", h + rng.normal(0, 0.01, h.shape), acc)
    res = fit_alignment([short], MagModel.identity(), REF.down_ut)
    assert not res.ok and "swept only" in res.refused
    tilted = LevelTurn("z", h, np.tile([0.0, 2.0, -9.6], (100, 1)))
    res = fit_alignment([tilted, tilted], MagModel.identity(), REF.down_ut)
    assert not res.ok and "not level" in res.refused


# ---------------------------------------------------------------------------------------------- refusals


@pytest.mark.parametrize("method", ["two-step", "three-step", "ellipsoid"])
def test_level_turns_only_are_refused_with_a_reason(method):
    """A boat turning level cannot determine a full-sphere model: each method says so instead of fitting."""
    block = simulate("level-turns", 120, rate_hz=RATE_HZ, seed=2)
    res = fit_mag(method, as_input(block), REF)
    assert not res.ok
    assert res.model == MagModel.identity()
    assert any(w in res.refused for w in ("coverage", "poorly determined", "ill-conditioned", "converge"))


@pytest.mark.parametrize("method", ["two-step", "three-step"])
def test_a_regression_the_turns_cannot_determine_is_refused_as_ill_conditioned(method):
    """Turns about one axis that leave x and y reading the same: the B_x and B_y columns of the thesis's
    regression are collinear, so both regressions refuse on their condition number (before solving)."""
    t = np.linspace(0.0, 2 * math.pi, 400)
    in_plane = np.outer(np.cos(t), [1.0, 1.0, 0.0]) / math.sqrt(2) + np.outer(np.sin(t), [0.0, 0.0, 1.0])
    mag = [5.0, 5.0, -3.0] + 50.0 * in_plane + 1e-9 * np.random.default_rng(0).standard_normal((len(t), 3))
    res = fit_mag(method, MagFitInput(t, mag), REF)
    assert not res.ok and "ill-conditioned" in res.refused
    assert res.quality["condition_number"] > 1e7


def test_too_few_and_non_finite_samples():
    block = tumble(errors_with([1, 2, 3], np.eye(3)), seconds=60)
    res = fit_mag("ellipsoid", MagFitInput(block.t_s[:10], block.mag_ut[:10]), REF)
    assert not res.ok and "too few samples" in res.refused
    mag = block.mag_ut.copy()
    mag[::7] = np.nan
    res = fit_mag("ellipsoid", MagFitInput(block.t_s, mag), REF)
    assert res.ok and res.quality["n_dropped_non_finite"] == len(mag[::7])


def test_disturbed_data_are_refused_for_large_residuals():
    block = tumble(errors_with([5, 5, 5], np.eye(3)), seconds=90)
    mag = block.mag_ut.copy()
    mag[: len(mag) // 3] += np.array([5.0, 0.0, 0.0])  # a magnet close by for a third of the run
    res = fit_mag("ellipsoid", MagFitInput(block.t_s, mag), REF)
    assert not res.ok and "halves of the recording give different calibrations" in res.refused


def test_without_reference_the_scale_follows_the_mean_radius():
    block = tumble(errors_with([1, 2, 3], np.eye(3) * 1.2), seconds=90)
    res = fit_mag("ellipsoid", MagFitInput(block.t_s, block.mag_ut), None)
    assert res.ok and res.quality["field_source"].startswith("mean raw norm")


# ---------------------------------------------------------------------------------------------- dispatch


def test_dispatch_knows_every_method_and_rejects_others():
    assert METHODS == ("ellipsoid", "two-step", "three-step", "backstepping")
    block = tumble(errors_with([1, 2, 3], np.eye(3)), seconds=60)
    with pytest.raises(ValueError, match="unknown magnetometer calibration method"):
        fit_mag("sphere", as_input(block), REF)
    with pytest.raises(TypeError):
        fit_mag("ellipsoid", block.mag_ut, REF)


def test_result_json_keys_are_the_public_interface():
    block = tumble(errors_with([1, 2, 3], np.eye(3)), seconds=60)
    d = fit_mag("ellipsoid", as_input(block), REF).to_json_dict()
    assert len(d["hard_iron_ut"]) == 3 and np.asarray(d["soft_iron"]).shape == (3, 3)
    assert isinstance(d["residual_rms_ut"], float) and d["refused"] is None
    assert isinstance(MagFitResult(MagModel.identity(), math.nan, "x").to_json_dict()["residual_rms_ut"], type(None))


def test_mag_fit_input_validates_shapes():
    with pytest.raises(ValueError, match="shape"):
        MagFitInput(np.arange(3.0), np.zeros((3, 2)))
    with pytest.raises(ValueError, match="rows"):
        MagFitInput(np.arange(3.0), np.zeros((4, 3)))
    with pytest.raises(ValueError, match="heading_ref_deg"):
        MagFitInput(np.arange(3.0), np.zeros((3, 3)), heading_ref_deg=np.zeros(2))
    d = MagFitInput(np.arange(4.0), np.ones((4, 3)), accel_m_s2=np.zeros((4, 3)))
    assert len(d.select(np.array([True, False, True, False]))) == 2
