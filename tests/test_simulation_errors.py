"""Sensor error model: ADIS16405 statistics, ideal sensor, Gauss–Markov bias, iron, validation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from ahrsd.simulation import SensorErrors, VehicleIron, open_stream, simulate
from ahrsd.simulation.errors import ErrorProcess

DEG = np.pi / 180.0
RATE = 819.2


def test_adis16405_defaults_match_the_anchor_figures():
    e = SensorErrors.adis16405(0)
    # ARW 2 °/√h, bias stability 0.007 °/s, VRW 0.2 m/s/√h, 0.2 mg, 1.25 mgauss rms (ADIS16405 datasheet, Rev. B)
    assert e.gyro_noise_density_rad_s_rthz == pytest.approx(2.0 / 60.0 * DEG)
    assert e.gyro_bias_instability_rad_s == pytest.approx(0.007 * DEG)
    assert e.accel_noise_density_m_s2_rthz == pytest.approx(0.2 / 60.0)
    assert e.accel_bias_instability_m_s2 == pytest.approx(0.2e-3 * 9.80665)
    std = e.noise_std(RATE)
    assert std["mag_ut"] == pytest.approx(0.125)                       # 1.25 mgauss at 819.2 SPS
    assert np.degrees(std["gyro_rad_s"]) == pytest.approx(0.954, abs=0.001)  # ≈ datasheet 0.9 °/s rms
    assert std["accel_m_s2"] / 9.80665 * 1e3 == pytest.approx(9.73, abs=0.01)  # ≈ datasheet 9 mg rms


def test_turn_on_errors_spread_as_documented_over_many_seeds():
    es = [SensorErrors.adis16405(s) for s in range(400)]
    gb = np.array([e.gyro_bias_rad_s for e in es])
    ab = np.array([e.accel_bias_m_s2 for e in es])
    gs = np.array([e.gyro_scale for e in es])
    # σ of a sample std from 1200 draws is ~2 %: ±8 % bounds cannot be met by a wrong σ of 0.2 or 0.05 °/s
    assert np.std(gb) == pytest.approx(0.1 * DEG, rel=0.08)
    assert np.std(ab) == pytest.approx(5e-3 * 9.80665, rel=0.08)
    assert np.std(gs) == pytest.approx(0.003, rel=0.08)
    assert abs(np.mean(gb)) < 4 * 0.1 * DEG / np.sqrt(gb.size)
    assert np.all(np.diag(es[0].gyro_misalignment_rad) == 0) and np.any(es[0].gyro_misalignment_rad != 0)


def test_static_noise_and_bias_within_statistical_bounds():
    n = 16384  # 20 s at 819.2 Hz
    stream = open_stream("static", seed=7)
    b = stream.next_block(n)
    e = stream.errors
    std = e.noise_std(RATE)
    for raw, truth, mat, bias, s in [
        (b.gyro_rad_s, b.truth_gyro_rad_s, e.gyro_matrix, b.truth_gyro_bias_rad_s, std["gyro_rad_s"]),
        (b.accel_m_s2, b.truth_accel_m_s2, e.accel_matrix, b.truth_accel_bias_m_s2, std["accel_m_s2"]),
    ]:
        resid = raw - truth @ mat.T - bias
        # sample std of n normals: relative σ = 1/√(2n) = 0.55 %; 4σ bound
        np.testing.assert_allclose(resid.std(axis=0), s, rtol=4 / np.sqrt(2 * n))
        assert np.all(np.abs(resid.mean(axis=0)) < 4 * s / np.sqrt(n))
    m_resid = b.mag_ut - b.truth_mag_ut @ e.soft_iron.T - e.hard_iron_ut
    np.testing.assert_allclose(m_resid.std(axis=0), std["mag_ut"], rtol=4 / np.sqrt(2 * n))
    # the mean output over 20 s estimates turn-on + in-run bias to within the noise
    mean_err = b.gyro_rad_s.mean(axis=0) - e.gyro_bias_rad_s
    assert np.all(np.abs(mean_err) < 4 * std["gyro_rad_s"] / np.sqrt(n) + 4 * e.gyro_bias_instability_rad_s)


def test_gauss_markov_bias_has_its_sigma_and_correlation_time():
    e = SensorErrors.ideal().replace(gyro_bias_instability_rad_s=0.007 * DEG, gyro_bias_corr_time_s=10.0)
    proc = ErrorProcess(e, rate_hz=5.0, seed=11)
    n = 100_000                     # 20 000 s = 2000 τ
    t = np.arange(n) / 5.0
    z = np.zeros((n, 3))
    _, _, _, _, gbias, _ = proc.apply(t, z, z, z)
    x = gbias.ravel(order="F").reshape(3, n)
    assert np.std(x) == pytest.approx(0.007 * DEG, rel=0.1)
    lag = 50                         # one τ at 5 Hz
    rho = np.mean([np.corrcoef(xi[:-lag], xi[lag:])[0, 1] for xi in x])
    assert rho == pytest.approx(np.exp(-1.0), abs=0.06)


@pytest.mark.parametrize("name", ["static", "rate-table", "coordinated-turn", "mag-disturbance"])
def test_ideal_errors_give_exact_truth(name):
    b = simulate(name, 3.0, rate_hz=100.0, errors="ideal")
    np.testing.assert_array_equal(b.gyro_rad_s, b.truth_gyro_rad_s)
    np.testing.assert_array_equal(b.accel_m_s2, b.truth_accel_m_s2)
    np.testing.assert_allclose(b.mag_ut, b.truth_mag_ut + b.truth_disturbance_ut, atol=1e-12)
    if name != "mag-disturbance":
        np.testing.assert_allclose(b.mag_ut, b.truth_mag_ut, atol=1e-12)
    assert np.all(b.temp_c == 25.0)


def test_ideal_sensor_on_an_iron_vehicle_only_shows_the_iron():
    stream = open_stream("level-turns", rate_hz=50.0, errors="ideal")
    b = stream.next_block(500)
    iron = VehicleIron.default()
    np.testing.assert_allclose(stream.errors.hard_iron_ut, iron.hard_iron_ut)
    np.testing.assert_allclose(stream.errors.soft_iron, iron.soft_iron)
    # a perfect calibration: inv(soft) · (raw − hard) recovers the Earth field
    cal = (b.mag_ut - stream.errors.hard_iron_ut) @ np.linalg.inv(stream.errors.soft_iron).T
    np.testing.assert_allclose(cal, b.truth_mag_ut, atol=1e-10)
    np.testing.assert_array_equal(b.gyro_rad_s, b.truth_gyro_rad_s)


def test_vehicle_iron_defaults_per_scenario_and_overrides():
    for name, has_iron in [("static", False), ("rate-table", False), ("coordinated-turn", False),
                           ("mag-disturbance", False), ("level-turns", True), ("tumble", True),
                           ("auv-out-and-back", True)]:
        s = open_stream(name, errors="ideal")
        assert (s.vehicle_iron is not None) == has_iron, name
        h = np.linalg.norm(s.errors.hard_iron_ut)
        assert (h > 20.0) if has_iron else (h == 0.0)
    assert open_stream("tumble", errors="ideal", vehicle_iron=None).vehicle_iron is None
    custom = VehicleIron(hard_iron_ut=[1.0, 2.0, 3.0], soft_iron=np.diag([1.1, 1.0, 0.9]))
    s = open_stream("static", errors="ideal", vehicle_iron=custom)
    np.testing.assert_allclose(s.errors.hard_iron_ut, [1, 2, 3])
    with pytest.raises(ValueError):
        open_stream("static", vehicle_iron="heavy")


def test_default_vehicle_iron_is_a_few_hundred_mgauss_and_non_symmetric():
    iron = VehicleIron.default()
    assert np.all((np.abs(iron.hard_iron_ut) >= 20.0) & (np.abs(iron.hard_iron_ut) <= 40.0))
    assert not np.allclose(iron.soft_iron, iron.soft_iron.T)


def test_sensor_and_vehicle_iron_compose_in_order():
    e = SensorErrors.adis16405(2)
    iron = VehicleIron.default()
    comb = e.with_vehicle_iron(iron)
    b_true = np.array([20.0, -5.0, 40.0])
    at_sensor = iron.soft_iron @ b_true + iron.hard_iron_ut
    expected = e.soft_iron @ at_sensor + e.hard_iron_ut
    np.testing.assert_allclose(comb.soft_iron @ b_true + comb.hard_iron_ut, expected)


def test_temperature_drift_follows_the_warm_up():
    e = SensorErrors.ideal().replace(gyro_bias_temp_rad_s_per_c=[0.01 * DEG, 0, 0], temp_warmup_c=6.0,
                                     temp_warmup_tau_s=100.0)
    b = simulate("static", 500.0, rate_hz=2.0, errors=e)
    expected_temp = 25.0 + 6.0 * (1 - np.exp(-b.t_s / 100.0))
    np.testing.assert_allclose(b.temp_c, expected_temp)
    np.testing.assert_allclose(b.gyro_rad_s[:, 0] - b.truth_gyro_rad_s[:, 0], 0.01 * DEG * (expected_temp - 25.0),
                               atol=1e-15)


def test_earth_rate_is_sensed_only_when_asked():
    from ahrsd.core.gravity import EARTH_RATE_RAD_S

    b = simulate("static", 1.0, rate_hz=10.0, errors="ideal", earth_rate=True)
    sensed = b.gyro_rad_s - b.truth_gyro_rad_s
    np.testing.assert_allclose(np.linalg.norm(sensed, axis=1), EARTH_RATE_RAD_S, rtol=1e-9)
    # level: the vertical component is −ω sin L (Groves 2nd ed. eq. 2.123)
    np.testing.assert_allclose(sensed[:, 2], -EARTH_RATE_RAD_S * np.sin(np.radians(36.42)), rtol=1e-9)


@pytest.mark.parametrize("kwargs, match", [
    ({"gyro_bias_rad_s": [1, 2]}, "gyro_bias_rad_s"),
    ({"gyro_misalignment_rad": np.eye(3)}, "diagonal"),
    ({"soft_iron": np.zeros((3, 3))}, "singular"),
    ({"gyro_noise_density_rad_s_rthz": -1.0}, "≥ 0"),
    ({"accel_bias_corr_time_s": 0.0}, "positive"),
    ({"hard_iron_ut": [np.nan, 0, 0]}, "finite"),
])
def test_invalid_errors_are_rejected_with_the_field_named(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SensorErrors.ideal().replace(**kwargs)


def test_errors_argument_is_checked():
    with pytest.raises(ValueError, match="adis16405"):
        open_stream("static", errors="perfect")
    e = SensorErrors.adis16405(5)
    assert open_stream("static", errors=e).errors is e


def test_sensor_errors_are_read_only():
    e = SensorErrors.adis16405(0)
    with pytest.raises(ValueError):
        e.gyro_bias_rad_s[0] = 1.0
    with pytest.raises(AttributeError):
        e.gyro_bias_rad_s = np.zeros(3)


@settings(derandomize=True, max_examples=30, deadline=None)
@given(n1=st.integers(1, 40), n2=st.integers(1, 40), n3=st.integers(1, 40), seed=st.integers(0, 2**31))
def test_blocks_concatenate_to_one_block(n1, n2, n3, seed):
    """Noise and bias processes continue across block boundaries (equal up to BLAS rounding, 1e-12)."""
    whole = open_stream("level-turns", rate_hz=100.0, seed=seed).next_block(n1 + n2 + n3)
    s = open_stream("level-turns", rate_hz=100.0, seed=seed)
    from ahrsd.simulation import SensorBlock
    parts = SensorBlock.concatenate([s.next_block(n1), s.next_block(n2), s.next_block(n3)])
    for f in ("t_s", "gyro_rad_s", "accel_m_s2", "mag_ut", "temp_c", "truth_q_wxyz", "truth_gyro_rad_s"):
        np.testing.assert_allclose(getattr(parts, f), getattr(whole, f), rtol=1e-12, atol=1e-12)


def test_same_seed_same_data_other_seed_other_data():
    a = simulate("tumble", 1.0, seed=4)
    b = simulate("tumble", 1.0, seed=4)
    c = simulate("tumble", 1.0, seed=5)
    np.testing.assert_array_equal(a.gyro_rad_s, b.gyro_rad_s)
    np.testing.assert_array_equal(a.mag_ut, b.mag_ut)
    assert not np.allclose(a.gyro_rad_s, c.gyro_rad_s)
    np.testing.assert_array_equal(a.truth_q_wxyz, c.truth_q_wxyz)  # truth does not depend on the seed


def test_stream_is_continuous_across_blocks_and_start_time_shifts_truth():
    s = open_stream("coordinated-turn", rate_hz=50.0, errors="ideal")
    a, b = s.next_block(100), s.next_block(100)
    assert b.t_s[0] - a.t_s[-1] == pytest.approx(0.02)
    late = open_stream("coordinated-turn", rate_hz=50.0, errors="ideal", start_s=2.0).next_block(100)
    np.testing.assert_allclose(late.t_s, b.t_s, atol=1e-12)
    np.testing.assert_allclose(late.truth_q_wxyz, b.truth_q_wxyz, atol=1e-12)


def test_next_block_rejects_non_positive_sizes_and_rates():
    with pytest.raises(ValueError):
        open_stream("static").next_block(0)
    with pytest.raises(ValueError):
        open_stream("static", rate_hz=0.0)


def test_small_and_large_requests_mix_without_changing_the_data():
    whole = open_stream("tumble", seed=9).next_block(1500)       # one direct evaluation
    s = open_stream("tumble", seed=9)
    sizes = [1, 1, 300, 37, 700, 461]                             # buffered and direct paths interleaved
    from ahrsd.simulation import SensorBlock
    parts = SensorBlock.concatenate([s.next_block(k) for k in sizes])
    assert s.samples_emitted == 1500
    for f in ("t_s", "gyro_rad_s", "accel_m_s2", "mag_ut", "truth_q_wxyz"):
        np.testing.assert_allclose(getattr(parts, f), getattr(whole, f), rtol=1e-12, atol=1e-12)


def test_block_rows_become_imu_samples():
    from ahrsd.core.sample import ImuSample, SampleFlags

    b = simulate("static", 0.01, rate_hz=819.2, seed=1)
    samples = list(b.samples(first_counter=100))
    assert len(samples) == len(b) == 8
    s = samples[3]
    assert isinstance(s, ImuSample) and s.counter == 103 and s.flags == SampleFlags.NEW_DATA
    np.testing.assert_array_equal(s.gyro_rad_s, b.gyro_rad_s[3])
    assert s.t_s == b.t_s[3] and s.temp_c == b.temp_c[3]


@settings(derandomize=True, max_examples=40, deadline=None)
@given(st.lists(st.floats(-0.05, 0.05), min_size=24, max_size=24), st.integers(0, 1000))
def test_deterministic_errors_are_exactly_matrix_times_truth_plus_bias(vals, seed):
    """Without noise or in-run drift: gyro = M ω + b, accel = M f + b, mag = S B + h, for any small errors."""
    v = np.array(vals)
    mis_g = np.array([[0, v[0], v[1]], [v[2], 0, v[3]], [v[4], v[5], 0]])
    mis_a = np.array([[0, v[6], v[7]], [v[8], 0, v[9]], [v[10], v[11], 0]])
    e = SensorErrors.ideal().replace(gyro_bias_rad_s=v[12:15], gyro_scale=v[15:18], gyro_misalignment_rad=mis_g,
                                     accel_bias_m_s2=v[18:21], accel_scale=v[21:24], accel_misalignment_rad=mis_a,
                                     hard_iron_ut=v[12:15] * 100, soft_iron=np.eye(3) + mis_g.T)
    s = open_stream("tumble", rate_hz=20.0, seed=seed, errors=e, vehicle_iron=None)
    b = s.next_block(40)
    np.testing.assert_allclose(b.gyro_rad_s, b.truth_gyro_rad_s @ e.gyro_matrix.T + e.gyro_bias_rad_s, atol=1e-12)
    np.testing.assert_allclose(b.accel_m_s2, b.truth_accel_m_s2 @ e.accel_matrix.T + e.accel_bias_m_s2, atol=1e-12)
    np.testing.assert_allclose(b.mag_ut, b.truth_mag_ut @ e.soft_iron.T + e.hard_iron_ut, atol=1e-10)
    # and the documented perfect calibrations undo them
    np.testing.assert_allclose((b.gyro_rad_s - e.gyro_bias_rad_s) @ np.linalg.inv(e.gyro_matrix).T,
                               b.truth_gyro_rad_s, atol=1e-12)


@pytest.mark.parametrize("phi", [0.0, 0.3, 0.99, 0.9999878, 1.0])
@pytest.mark.parametrize("n", [0, 1, 7, 5000])
def test_first_order_recursion_is_the_iir_filter(phi, n):
    """The simulator's Gauss–Markov recursion against scipy's IIR filter of the same difference equation."""
    from scipy.signal import lfilter

    from ahrsd.simulation.errors import first_order_recursion

    rng = np.random.default_rng(3)
    w, state = rng.standard_normal((n, 3)), rng.standard_normal(3)
    out, last = first_order_recursion(phi, w, state)
    if n == 0:
        assert out.shape == (0, 3) and np.array_equal(last, state)
        return
    ref, _ = lfilter([1.0], [1.0, -phi], w, axis=0, zi=(phi * state)[None, :])
    np.testing.assert_allclose(out, ref, rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(last, out[-1])
