"""The thesis filter: its Q/R, accuracy on the simulated ADIS16405 against the thesis's accuracy figures,
convergence, bias learning, time gaps, invalid sensors and the Estimator protocol."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ahrsd.core.sample import SampleFlags, make_sample
from ahrsd.core.estimate import EstimateFlags
from ahrsd.estimator import make_estimator
from ahrsd.core.angles import wrap_pi
from ahrsd.estimator.rotations import euler_to_quat, quat_angle_between, quat_multiply, quat_to_euler
from ahrsd.estimator.thesis_kf import ThesisKf, ThesisKfParams
from ahrsd.simulation import DEFAULT_SITE, SensorErrors, open_stream

RATE_HZ = 819.2
DECL = DEFAULT_SITE.earth_field().declination_rad


def calibrated_errors(seed: int, gyro_bias_deg_s=(0.0, 0.0, 0.0)) -> SensorErrors:
    """An ADIS16405 after a perfect calibration: datasheet noise and in-run bias instability remain."""
    z3, z33 = np.zeros(3), np.zeros((3, 3))
    return SensorErrors.adis16405(seed).replace(
        gyro_bias_rad_s=np.radians(gyro_bias_deg_s), gyro_scale=z3, gyro_misalignment_rad=z33,
        accel_bias_m_s2=z3, accel_scale=z3, accel_misalignment_rad=z33, hard_iron_ut=z3, soft_iron=np.eye(3))


def simulate(scenario: str, seconds: float, seed: int = 1, rate_hz: float = RATE_HZ, errors=None):
    stream = open_stream(scenario, rate_hz=rate_hz, seed=seed, errors=errors or calibrated_errors(seed),
                         vehicle_iron=None)
    return stream.next_block(int(round(seconds * rate_hz)))


def run(kf, block, start: int = 0):
    n = len(block)
    q = np.zeros((n, 4))
    flags = np.zeros(n, dtype=int)
    last = None
    for i in range(start, n):
        last = kf.update(make_sample(block.t_s[i], block.gyro_rad_s[i], block.accel_m_s2[i], block.mag_ut[i]))
        q[i] = last.q_wxyz
        flags[i] = int(last.flags)
    return q, flags, last


def errors_deg(q_est_mag, q_truth):
    """Roll, pitch, yaw errors (deg) of magnetic-north estimates against true-north truth."""
    q_true_north = quat_multiply(euler_to_quat(0.0, 0.0, DECL), q_est_mag)
    return np.degrees(wrap_pi(quat_to_euler(q_true_north) - quat_to_euler(q_truth)))


def rms(a, axis=0):
    return np.sqrt(np.mean(np.square(a), axis=axis))


# ------------------------------------------------------------------------------------------- the thesis's numbers
def test_q_and_r_are_the_thesis_tuning():
    p = ThesisKfParams()
    # worked: (3·[0.05, 0.05, 0.06, 0.005, 0.005, 0.006] °/√s)² = diag(6.854e-6, 6.854e-6, 9.870e-6, 6.854e-8, 6.854e-8, 9.870e-8) rad²/s
    np.testing.assert_allclose(p.q_diag, [6.854e-6, 6.854e-6, 9.870e-6, 6.854e-8, 6.854e-8, 9.870e-8], rtol=1e-3)
    # R: diag(0.74², 0.66², 0.52², 3.65², 3.44², 3.72²) in mG² and mg², here in µT² and (m/s²)²
    r = p.r_diag / np.array([0.01] * 3 + [(9.80665e-3) ** 2] * 3)
    np.testing.assert_allclose(r, [0.5476, 0.4356, 0.2704, 13.3225, 11.8336, 13.8384], rtol=1e-12)


def test_noise_free_data_give_the_exact_attitude_both_versions():
    block = simulate("rate-table", 4.0, errors=SensorErrors.ideal())
    for version in (1, 2):
        q, _, _ = run(ThesisKf(wahba_version=version), block)
        err = quat_angle_between(quat_multiply(euler_to_quat(0.0, 0.0, DECL), q[1:]), block.truth_q_wxyz[1:])
        assert np.degrees(err.max()) < 0.02, version  # only the F = I + AΔt + ½A²Δt² truncation error at 90 °/s remains


# ------------------------------------------------------------------------------------ accuracy (the thesis's figures)
@pytest.mark.parametrize("version", [2, 1])
def test_static_accuracy_beats_the_thesis_table(version):
    block = simulate("static", 10.0, seed=3)
    q, flags, _ = run(ThesisKf(wahba_version=version), block)
    settled = (flags & int(EstimateFlags.INITIALISING)) == 0
    assert settled[-1] and settled.sum() > 0.85 * len(block)
    err = rms(errors_deg(q[settled], block.truth_q_wxyz[settled]))
    print(f"thesis v{version} static RMS roll {err[0]:.3f}° pitch {err[1]:.3f}° heading {err[2]:.3f}°")
    assert err[0] < 0.2 and err[1] < 0.2 and err[2] < 0.4


def test_rate_table_accuracy_within_the_thesis_dynamic_figure():
    block = simulate("rate-table", 30.0, seed=4)   # hold, ±90 °/s table turns about the vertical
    q, flags, _ = run(ThesisKf(), block)
    settled = (flags & int(EstimateFlags.INITIALISING)) == 0
    err = rms(errors_deg(q[settled], block.truth_q_wxyz[settled]))
    print(f"thesis rate-table RMS roll {err[0]:.3f}° pitch {err[1]:.3f}° heading {err[2]:.3f}°")
    assert np.all(err < 0.5)


def test_any_sample_rate():
    block = simulate("static", 10.0, seed=5, rate_hz=100.0)
    q, flags, _ = run(ThesisKf(), block)
    settled = (flags & int(EstimateFlags.INITIALISING)) == 0
    err = rms(errors_deg(q[settled], block.truth_q_wxyz[settled]))
    assert err[0] < 0.2 and err[1] < 0.2 and err[2] < 0.4


# ----------------------------------------------------------------------------------- convergence and bias
def test_converges_from_a_wrong_start():
    block = simulate("static", 4.0, seed=6)
    kf = ThesisKf()
    # Initialise on a sample rotated by 60° in yaw and 20° in roll (as if the unit moved while starting up).
    wrong = np.array(quat_to_dcm_T(euler_to_quat(0.35, 0.0, 1.05)))
    kf.update(make_sample(-0.01, [0, 0, 0], wrong @ block.accel_m_s2[0], wrong @ block.mag_ut[0]))
    first = kf.update(make_sample(block.t_s[0], block.gyro_rad_s[0], block.accel_m_s2[0], block.mag_ut[0]))
    assert quat_angle_between(first.q_wxyz, quat_multiply(euler_to_quat(0, 0, -DECL), block.truth_q_wxyz[0])) > 0.5
    q, _, last = run(kf, block, start=1)
    err = rms(errors_deg(q[-1638:], block.truth_q_wxyz[-1638:]))   # the last 2 s
    assert np.all(err < 0.3)
    assert not last.flags & EstimateFlags.INITIALISING


def quat_to_dcm_T(q):
    from ahrsd.estimator.rotations import quat_to_dcm

    return quat_to_dcm(q).T


def test_learns_a_residual_gyro_bias_while_static():
    bias_deg_s = np.array([0.3, -0.2, 0.25])
    block = simulate("static", 12.0, seed=2, errors=calibrated_errors(2, bias_deg_s))
    _, _, last = run(ThesisKf(), block)
    assert np.all(np.abs(np.degrees(last.gyro_bias_rad_s) - bias_deg_s) < 0.06)
    np.testing.assert_allclose(last.rate_body_rad_s, block.gyro_rad_s[-1] - last.gyro_bias_rad_s)


# ------------------------------------------------------------------------------------------ time and validity
def test_large_time_gap_is_flagged_and_propagated():
    block = simulate("rate-table", 14.0, seed=7)   # turning at up to 90 °/s after the 5 s hold
    keep = np.ones(len(block), dtype=bool)
    gap = (block.t_s > 9.0) & (block.t_s < 9.3)    # 0.3 s of samples lost mid-turn
    keep[gap] = False
    idx = np.flatnonzero(keep)
    kf = ThesisKf()
    worst_after = 0.0
    seen_gap_flag = False
    for i in idx:
        e = kf.update(make_sample(block.t_s[i], block.gyro_rad_s[i], block.accel_m_s2[i], block.mag_ut[i]))
        if block.t_s[i] >= 9.3 and not seen_gap_flag:
            assert e.flags & EstimateFlags.LARGE_DT and not e.flags & EstimateFlags.REINITIALISED
            seen_gap_flag = True
        elif block.t_s[i] > 9.5:
            assert not e.flags & EstimateFlags.LARGE_DT
            err = quat_angle_between(quat_multiply(euler_to_quat(0, 0, DECL), e.q_wxyz), block.truth_q_wxyz[i])
            worst_after = max(worst_after, math.degrees(err))
    assert seen_gap_flag and worst_after < 0.5


def test_very_long_gap_or_time_going_backwards_reinitialises():
    block = simulate("static", 3.0, seed=8)
    kf = ThesisKf()
    run(kf, block)
    s = block.accel_m_s2[-1], block.mag_ut[-1]
    e = kf.update(make_sample(block.t_s[-1] + 5.0, [0, 0, 0], *s))
    assert e.flags & EstimateFlags.REINITIALISED and e.flags & EstimateFlags.LARGE_DT
    assert e.flags & EstimateFlags.INITIALISING
    e = kf.update(make_sample(block.t_s[-1], [0, 0, 0], *s))   # back in time
    assert e.flags & EstimateFlags.REINITIALISED
    assert np.isfinite(e.roll_rad)


def test_invalid_sensors_are_skipped_not_fatal():
    block = simulate("static", 2.0, seed=9)
    kf = ThesisKf()
    q, _, last = run(kf, block)
    t = block.t_s[-1]
    g, a, m = block.gyro_rad_s[-1], block.accel_m_s2[-1], block.mag_ut[-1]
    e = kf.update(make_sample(t + 1 / RATE_HZ, g, a, [np.nan, 0, 0]))
    assert e.flags & EstimateFlags.MAG_REJECTED and np.all(np.isfinite(e.q_wxyz))
    e = kf.update(make_sample(t + 2 / RATE_HZ, g, [np.inf, 0, 0], m))
    assert e.flags & EstimateFlags.ACCEL_REJECTED and np.all(np.isfinite(e.q_wxyz))
    e = kf.update(make_sample(t + 3 / RATE_HZ, g, a, m, flags=SampleFlags.MAG_INVALID | SampleFlags.ACCEL_INVALID))
    assert e.flags & EstimateFlags.MAG_REJECTED and e.flags & EstimateFlags.ACCEL_REJECTED
    e = kf.update(make_sample(t + 4 / RATE_HZ, [np.nan] * 3, a, m))
    assert np.all(np.isfinite(e.q_wxyz)) and quat_angle_between(e.q_wxyz, last.q_wxyz) < math.radians(0.5)


def test_no_usable_first_sample_gives_an_uninitialised_estimate():
    kf = ThesisKf()
    e = kf.update(make_sample(0.0, [0, 0, 0], [0, 0, -9.8], [np.nan, 1, 1]))
    assert e.flags & EstimateFlags.INITIALISING and math.isnan(e.roll_rad)
    e = kf.update(make_sample(0.01, [0, 0, 0], [0, 0, 0.0], [20, 0, 40]))  # free fall: no gravity direction
    assert math.isnan(e.yaw_rad)
    e = kf.update(make_sample(0.02, [0, 0, 0], [0, 0, -9.8], [0, 0, 40]))   # field parallel to gravity
    assert math.isnan(e.yaw_rad)
    e = kf.update(make_sample(0.03, [0, 0, 0], [0, 0, -9.8], [20, 0, 40]))
    assert abs(e.yaw_rad) < 1e-9 and abs(e.roll_rad) < 1e-9 and abs(e.pitch_rad) < 1e-9


# ---------------------------------------------------------------------------------------- protocol and outputs
def test_estimate_fields_heading_and_declination():
    block = simulate("static", 2.0, seed=10)
    kf = make_estimator("thesis", declination_rad=math.radians(350.0))
    assert kf.name == "thesis" and isinstance(kf, ThesisKf)
    _, _, e = run(kf, block)
    assert math.isclose(e.heading_mag_rad, e.yaw_rad % (2 * math.pi))
    assert math.isclose(e.heading_true_rad, (e.yaw_rad + math.radians(350.0)) % (2 * math.pi))
    assert 0 <= e.heading_true_rad < 2 * math.pi
    roll, pitch, yaw = quat_to_euler(e.q_wxyz)
    assert math.isclose(roll, e.roll_rad, abs_tol=1e-12) and math.isclose(yaw, e.yaw_rad, abs_tol=1e-12)
    assert math.isclose(np.linalg.norm(e.q_wxyz), 1.0, abs_tol=1e-12)
    assert e.sigma_rpy_rad.shape == (3,) and np.all(e.sigma_rpy_rad > 0) and np.all(e.sigma_rpy_rad < 0.01)
    kf.set_declination(0.0)
    e2 = kf.update(make_sample(block.t_s[-1] + 1 / RATE_HZ, block.gyro_rad_s[-1], block.accel_m_s2[-1], block.mag_ut[-1]))
    assert math.isclose(e2.heading_true_rad, e2.heading_mag_rad)
    kf.reset()
    e3 = kf.update(make_sample(block.t_s[-1] + 2 / RATE_HZ, block.gyro_rad_s[-1], block.accel_m_s2[-1], block.mag_ut[-1]))
    assert e3.flags & EstimateFlags.INITIALISING


def test_initialising_until_settled_then_clear():
    block = simulate("static", 2.0, seed=11)
    _, flags, _ = run(ThesisKf(settle_time_s=0.5), block)
    init = (flags & int(EstimateFlags.INITIALISING)) != 0
    first_clear = np.argmin(init)
    assert init[0] and not init[-1]
    assert abs(block.t_s[first_clear] - 0.5) < 0.01 and not init[first_clear:].any()


def test_fixed_reference_field_sets_the_dip():
    f = DEFAULT_SITE.earth_field()
    kf = ThesisKf(mag_reference_ned_ut=tuple(f.ned_ut))
    assert math.isclose(kf.dip_rad, f.inclination_rad, rel_tol=1e-12)
    block = simulate("static", 3.0, seed=12)
    q, flags, _ = run(kf, block)
    settled = (flags & int(EstimateFlags.INITIALISING)) == 0
    assert np.all(rms(errors_deg(q[settled], block.truth_q_wxyz[settled])) < 0.4)


def test_parameters_are_validated():
    with pytest.raises(ValueError, match="unknown thesis parameter"):
        ThesisKf(nonsense=1)
    # the kind, as every estimator's parameters (estimator/params.py): `replay --set q_inflation=high` is text
    with pytest.raises(ValueError, match="q_inflation: expected a number"):
        ThesisKf(q_inflation="high")
    with pytest.raises(ValueError):
        ThesisKf(wahba_version=3)
    with pytest.raises(ValueError):
        ThesisKf(mag_noise_ut=(0.1, -0.1, 0.1))
    with pytest.raises(ValueError):
        ThesisKf(bias_time_constant_s=0.0)
    with pytest.raises(ValueError):
        ThesisKf(mag_reference_ned_ut=(0.0, 0.0, 40.0))


def test_initial_covariance_is_r_and_the_bias_prior():
    p = ThesisKfParams()
    kf = ThesisKf(initial_bias_sigma_rad_s=0.01, initial_bias_rad_s=(0.001, -0.002, 0.003))
    e = kf.update(make_sample(0.0, [0, 0, 0], [0.3, -0.2, -9.8], [21.0, 2.0, 41.0]))
    np.testing.assert_allclose(np.diag(kf.covariance), np.concatenate((p.r_diag, [1e-4] * 3)))
    np.testing.assert_allclose(kf.state, [21.0, 2.0, 41.0, -0.3, 0.2, 9.8, 0.001, -0.002, 0.003])  # x₀ = [m̃, −f̃, b₀]
    np.testing.assert_allclose(e.gyro_bias_rad_s, [0.001, -0.002, 0.003])


def test_bias_is_a_gauss_markov_process_with_time_constant_tau():
    # With no measurements (both flagged invalid) the bias estimate decays as exp(−t/τ_w) (the Gauss–Markov model).
    tau = 50.0
    kf = ThesisKf(bias_time_constant_s=tau, initial_bias_rad_s=(0.01, -0.02, 0.005))
    kf.update(make_sample(0.0, [0, 0, 0], [0, 0, -9.8], [20.0, 0, 40.0]))
    dt = 1 / 100.0
    bad = SampleFlags.MAG_INVALID | SampleFlags.ACCEL_INVALID
    for k in range(1, 1001):
        e = kf.update(make_sample(k * dt, [0, 0, 0], [0, 0, -9.8], [20.0, 0, 40.0], flags=bad))
    np.testing.assert_allclose(e.gyro_bias_rad_s, np.array([0.01, -0.02, 0.005]) * math.exp(-10.0 / tau), rtol=1e-6)
