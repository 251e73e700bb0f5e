"""Driver + simulated chip on the real simulation streams: the chip reproduces the stream to the LSB, the
averaging filter behaves like its taps, and a static/rotating run matches the configured errors and truth."""

import math

import numpy as np
import pytest


from ahrsd.drivers import registers as R  # noqa: E402
from ahrsd.drivers.adis16405 import Adis16405  # noqa: E402
from ahrsd.core.sample import SampleFlags  # noqa: E402
from ahrsd.drivers.simulated import SimulatedAdis16405  # noqa: E402
from ahrsd.simulation import open_stream  # noqa: E402

RATE = R.sample_rate_hz(R.SMPL_PRD_DEFAULT)
LSB = np.array([R.GYRO_RAD_S_PER_LSB] * 3 + [R.ACCEL_M_S2_PER_LSB] * 3 + [R.MAG_UT_PER_LSB] * 3)


def run(scenario, n, seed=0, errors="adis16405", filter_n=None):
    chip = SimulatedAdis16405(scenario, seed=seed, errors=errors)
    imu = Adis16405(chip)
    imu.start(filter_n=filter_n)
    out = np.empty((n, 9))
    t = np.empty(n)
    q = np.empty((n, 4))
    for k in range(n):
        s = imu.read_sample()
        assert s.flags & SampleFlags.NEW_DATA and not s.flags & SampleFlags.STALE
        out[k, 0:3], out[k, 3:6], out[k, 6:9] = s.gyro_rad_s, s.accel_m_s2, s.mag_ut
        t[k] = s.t_s
        q[k] = chip.output_truth_q_wxyz
    block = open_stream(scenario, rate_hz=RATE, seed=seed, errors=errors).next_block(n)
    return imu, chip, t, out, q, block


def stream_values(block):
    return np.column_stack([block.gyro_rad_s, block.accel_m_s2, block.mag_ut])


def test_unfiltered_output_is_the_stream_quantised_to_the_lsb():
    imu, chip, t, out, q, block = run("tumble", 3000, seed=2, filter_n=0)
    assert np.allclose(t, block.t_s, atol=1e-9)
    err = np.abs(out - stream_values(block)) / LSB
    assert err.max() <= 0.5 + 1e-6
    assert np.allclose(q, block.truth_q_wxyz)
    assert imu.counters["garbage_frames"] == 0 and chip.stats["clock_violations"] == 0


def test_filtered_output_is_the_bartlett_filtered_stream():
    n_filter = 3
    imu, chip, t, out, q, block = run("rate-table", 3000, seed=5, filter_n=n_filter)
    taps = R.bartlett_taps(n_filter)
    raw = stream_values(block)
    # the chip starts with its filter history full of the first sample (no start-up transient)
    padded = np.vstack([np.repeat(raw[:1], len(taps) - 1, axis=0), raw])
    expected = np.column_stack([np.convolve(padded[:, i], taps, mode="valid") for i in range(9)])
    err = np.abs(out - expected) / LSB
    assert err.max() <= 0.5 + 1e-6


def test_static_run_has_the_configured_mean_and_noise():
    n = 8192                                                  # 10 s
    stream = open_stream("static", rate_hz=RATE, seed=11)
    e = stream.errors
    imu, chip, t, out, q, block = run("static", n, seed=11)  # chip default: SENS_AVG N = 2
    shrink = math.sqrt(np.sum(R.bartlett_taps(2) ** 2))       # white noise through the 7 Bartlett taps
    # gyro: mean = truth (0 here) + the configured bias; noise = ARW density × sqrt(rate) through the filter
    resid = out[:, 0:3] - block.truth_gyro_rad_s
    sigma_raw = e.gyro_noise_density_rad_s_rthz * math.sqrt(RATE)
    tol = 4 * sigma_raw / math.sqrt(n) + 3 * e.gyro_bias_instability_rad_s + R.GYRO_RAD_S_PER_LSB / 2
    assert np.allclose(resid.mean(axis=0), e.gyro_bias_rad_s, atol=tol)
    expected_std = np.hypot(sigma_raw * shrink, R.GYRO_RAD_S_PER_LSB / math.sqrt(12))
    assert np.allclose(out[:, 0:3].std(axis=0), expected_std, rtol=0.08)
    # accelerometer and magnetometer: same means as the stream, noise density through filter and quantiser
    for sl, density, lsb in ((slice(3, 6), e.accel_noise_density_m_s2_rthz, R.ACCEL_M_S2_PER_LSB),
                             (slice(6, 9), e.mag_noise_density_ut_rthz, R.MAG_UT_PER_LSB)):
        raw = stream_values(block)[:, sl]
        assert np.allclose(out[:, sl].mean(axis=0), raw.mean(axis=0), atol=0.05 * lsb + 4 * raw.std() / math.sqrt(n))
        expected_std = np.hypot(density * math.sqrt(RATE) * shrink, lsb / math.sqrt(12))
        assert np.allclose(out[:, sl].std(axis=0), expected_std, rtol=0.1)
    # at rest the up axis (z is down in FRD) reads -g and the field is the site's
    assert out[:, 5].mean() == pytest.approx(-9.81, abs=0.15)
    assert np.allclose(out[:, 6:9].mean(axis=0), block.truth_mag_ut.mean(axis=0), atol=2.0)


def test_rotating_run_matches_truth_within_quantisation():
    imu, chip, t, out, q, block = run("rate-table", 8192, errors="ideal", filter_n=0)
    assert np.abs(block.truth_gyro_rad_s).max() > math.radians(50)
    err = np.abs(out[:, 0:3] - block.truth_gyro_rad_s) / R.GYRO_RAD_S_PER_LSB
    assert err.max() <= 0.5 + 1e-6
    err = np.abs(out[:, 3:6] - block.truth_accel_m_s2) / R.ACCEL_M_S2_PER_LSB
    assert err.max() <= 0.5 + 1e-6
    assert np.allclose(q, block.truth_q_wxyz)


def test_rotating_run_with_sensor_errors_stays_within_noise_and_error_budget():
    imu, chip, t, out, q, block = run("tumble", 8192, seed=3, filter_n=0)
    e = open_stream("tumble", rate_hz=RATE, seed=3).errors
    resid = out[:, 0:3] - block.truth_gyro_rad_s - block.truth_gyro_bias_rad_s
    sigma = e.gyro_noise_density_rad_s_rthz * math.sqrt(RATE)
    # what is left: white noise + scale/misalignment × rate (≤ 1 % of 131 °/s) + quantisation
    budget = np.sqrt(sigma ** 2 + (0.01 * np.abs(block.truth_gyro_rad_s).max()) ** 2 + R.GYRO_RAD_S_PER_LSB ** 2 / 12)
    assert np.all(np.sqrt(np.mean(resid ** 2, axis=0)) < budget)
    assert np.all(np.sqrt(np.mean(resid ** 2, axis=0)) > 0.8 * sigma)       # the noise is really there


def test_rate_change_reopens_the_stream_at_the_new_rate():
    chip = SimulatedAdis16405("static", seed=1)
    imu = Adis16405(chip)
    imu.start(smpl_prd=0x07)                                   # 204.8 SPS
    t = [imu.read_sample().t_s for _ in range(100)]
    assert np.allclose(np.diff(t), 1 / R.sample_rate_hz(0x07))
    assert chip.sample_rate_hz == pytest.approx(204.8, rel=1e-4)
