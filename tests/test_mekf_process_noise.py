"""mekf's tilt process noise, the one rate the covariance propagation and the published σ both use: the gyro's
angle random walk plus its rate-proportional errors, σ_g² + (σ_s·|ω|)² per second (MekfParams
gyro_noise_rad_s_sqrt_hz, gyro_rate_noise_sqrt_s). Truth is worked out here with numpy and scipy from the
parameters (Φ P Φᵀ + Q as matrices), never with the kernel's unrolled blocks.

One step with the accelerometer and magnetometer flagged invalid only propagates, so the covariance after it is
exactly Φ P Φᵀ + Q; the published σ adds that rate over the low-passed vertical's age acc_lowpass_tau_s."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.core.sample import SampleFlags, make_sample
from ahrsd.estimator.mekf import Mekf

DT_S = 1.0 / 819.2
RATE_RAD_S = np.array([0.3, -0.2, 0.5])          # a turn fast enough for the rate term to matter
RATE_NOISE_SQRT_S = 3e-3                          # σ_s: (σ_s·|ω|)² ≈ 9× the default σ_g² at this rate
FIELD_BODY_UT = np.array([20.0, 5.0, 40.0])
TILTED_ACC_M_S2 = np.array([1.2, -0.8, -9.7])     # not level, so C has no zero entries


def _initialised_then_one_propagation():
    f = Mekf(gyro_rate_noise_sqrt_s=RATE_NOISE_SQRT_S, turn_speed_m_s=0.0, accel_bias_sigma_m_s2=0.0,
             accel_axes_tilt_sigma_rad=0.0)
    f.update(make_sample(10.0, np.zeros(3), TILTED_ACC_M_S2, FIELD_BODY_UT))
    p_before = f.covariance
    bias = f.gyro_bias_rad_s
    no_aiding = SampleFlags.ACCEL_INVALID | SampleFlags.MAG_INVALID
    out = f.update(make_sample(10.0 + DT_S, RATE_RAD_S, TILTED_ACC_M_S2, FIELD_BODY_UT, flags=no_aiding))
    return f, p_before, bias, out


def _tilt_noise_rate_rad2_s(f: Mekf, rate_rad_s: np.ndarray) -> float:
    p = f.params
    return p.gyro_noise_rad_s_sqrt_hz ** 2 + (p.gyro_rate_noise_sqrt_s * float(np.linalg.norm(rate_rad_s))) ** 2


def test_a_step_without_aiding_propagates_the_covariance_with_the_rate_dependent_tilt_noise():
    """P' = Φ P Φᵀ + Q, Φ = [[I, −C Δt], [0, I]], Q = diag(q_t, q_t, σ_g² Δt, σ_b² Δt ×3) with
    q_t = (σ_g² + (σ_s |ω|)²) Δt. (Broken by dropping the rate term from the tilt noise: P_NN off by 4.2e-9 against
    a 1e-15 tolerance.)"""
    f, p_before, bias, out = _initialised_then_one_propagation()
    q = np.asarray(out.q_wxyz)
    c = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()   # C_b^n after the step's attitude propagation
    phi = np.eye(6)
    phi[:3, 3:] = -c * DT_S
    p = f.params
    q_tilt = _tilt_noise_rate_rad2_s(f, RATE_RAD_S - bias) * DT_S
    q_noise = np.diag([q_tilt, q_tilt, p.gyro_noise_rad_s_sqrt_hz ** 2 * DT_S]
                      + [p.gyro_bias_walk_rad_s_sqrt_s ** 2 * DT_S] * 3)
    expected = phi @ p_before @ phi.T + q_noise
    assert q_tilt > 5.0 * p.gyro_noise_rad_s_sqrt_hz ** 2 * DT_S   # the rate term dominates: the check can see it
    np.testing.assert_allclose(f.covariance, expected, rtol=0.0, atol=1e-15)


def test_the_published_tilt_sigma_adds_the_tilt_noise_over_the_vertical_s_age():
    """σ_roll² + σ_pitch² = P_NN + P_EE + 2 (σ_g² + (σ_s |ω − b|)²) τ, b the bias after the step (the trace does not depend on the yaw the
    tilt is rotated by; turn_speed_m_s = 0 and no tilt update leave no turn lean, accel_bias_sigma_m_s2 = 0 no
    accelerometer bias term, accel_axes_tilt_sigma_rad = 0 no misalignment term). (Broken by dropping the rate
    term from the published σ: the age term 5.1e-7 against 5.6e-6 rad².)"""
    f, _, _, out = _initialised_then_one_propagation()
    p_now = f.covariance
    sig = np.asarray(out.sigma_rpy_rad)
    age_term = 0.5 * (sig[0] ** 2 + sig[1] ** 2 - p_now[0, 0] - p_now[1, 1])
    expected = _tilt_noise_rate_rad2_s(f, RATE_RAD_S - f.gyro_bias_rad_s) * f.params.acc_lowpass_tau_s
    assert age_term == pytest.approx(expected, rel=1e-6)
    assert math.isclose(sig[2] ** 2, p_now[2, 2], rel_tol=1e-12)   # heading: no age term
