"""Allan-variance analysis (calibration/allan.py): the estimator itself, and recovery of known noise.

Recovery tolerance: 10 % (the issue's requirement). The data are long enough for that: 24 h at 1 Hz
(86 400 samples, generated directly at that rate — the noise models are defined by densities, so a low rate
is the same process averaged). For flicker noise the relative 1σ of the flat-region reading over 24 h is
about 4 % (measured over 12 seeds while writing this test), so 10 % is 2.5σ; white noise is read to < 1 %.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from ahrsd.calibration.allan import (
    FLICKER_FACTOR,
    AllanResult,
    NoiseParameters,
    allan_deviation,
    analyse_static,
    gauss_markov_avar,
    kalman_tuning,
    load_noise_parameters,
    save_noise_parameters,
)

DAY_S = 86_400


def flicker_noise(n: int, rate_hz: float, b: float, rng) -> np.ndarray:
    """1/f (bias-instability) noise with IEEE Std 952 coefficient B: two-sided PSD B²/(2π f), i.e.
    one-sided B²/(π f), shaped in the frequency domain. Its Allan deviation is flat at 0.664·B."""
    w = np.fft.rfft(rng.standard_normal(n))
    f = np.fft.rfftfreq(n, 1.0 / rate_hz)
    psd = np.zeros_like(f)
    psd[1:] = b * b / (math.pi * f[1:])
    return np.fft.irfft(w * np.sqrt(psd * rate_hz / 2.0), n)


def test_overlapping_allan_variance_matches_the_definition():
    """σ²(τ) = 1/(2τ²(N−2m)) Σ (θ_{k+2m} − 2θ_{k+m} + θ_k)², written out with loops on a short series."""
    rng = np.random.default_rng(3)
    x = rng.normal(size=200) + np.linspace(0, 1, 200)
    rate = 10.0
    taus, adev, n_terms = allan_deviation(x, rate, m=np.array([1, 3, 7, 20]), overlap_stride=0)
    theta = np.concatenate([[0.0], np.cumsum(x - x.mean())]) / rate
    for tau, value, nt, m in zip(taus, adev, n_terms, [1, 3, 7, 20]):
        terms = [(theta[k + 2 * m] - 2 * theta[k + m] + theta[k]) ** 2 for k in range(len(x) + 1 - 2 * m)]
        assert nt == len(terms)
        assert value == pytest.approx(math.sqrt(sum(terms) / (2 * tau * tau * len(terms))), rel=1e-10)
    # Cluster-mean form of the thesis (eq. 5-3…5-7) for m = 1: ½ mean of squared differences of samples.
    assert adev[0] ** 2 == pytest.approx(0.5 * np.mean(np.diff(x) ** 2), rel=1e-10)
    # The strided option agrees with the textbook form where there are many clusters.
    y = rng.normal(size=20000)
    _, full, _ = allan_deviation(y, rate, m=np.array([1, 8, 64]))
    _, fast, _ = allan_deviation(y, rate, m=np.array([1, 8, 64]), overlap_stride=0.125)
    np.testing.assert_allclose(fast, full, rtol=0.05)


def test_gauss_markov_allan_variance_limits():
    tc = 100.0
    # τ ≫ Tc: like white noise of density² 2σ²Tc; τ ≪ Tc: like a rate random walk, σ² ≈ 2τ/(3Tc)·σ²... → 0.
    assert gauss_markov_avar(np.array([1e6]), tc)[0] == pytest.approx(2 * tc / 1e6, rel=1e-3)
    assert gauss_markov_avar(np.array([1e-4]), tc)[0] == pytest.approx(2 / 3 * 1e-4 / tc, rel=1e-3)
    peak = np.max(np.sqrt(gauss_markov_avar(np.geomspace(1, 1e4, 2000), tc)))
    assert peak == pytest.approx(0.6174, abs=2e-3)  # the classic ≈0.62σ bump at τ ≈ 1.9 Tc


def test_white_plus_flicker_recovered_within_10_percent():
    rng = np.random.default_rng(20)
    rate = 1.0
    n = DAY_S
    arw = math.radians(2.0) / 60.0          # 2 °/√h (ADIS16405 datasheet)
    bias = math.radians(0.007)             # 0.007 °/s (ADIS16405 datasheet)
    gyro = rng.normal(size=(n, 3)) * arw * math.sqrt(rate) + np.column_stack(
        [flicker_noise(n, rate, bias, rng) for _ in range(3)])
    res = analyse_static(np.arange(n) / rate, gyro_rad_s=gyro)
    for ax, p in res.parameters["gyro"].items():
        assert p.white_noise == pytest.approx(arw, rel=0.10), ax
        assert p.bias_instability == pytest.approx(bias, rel=0.10), ax


def test_simulator_arw_vrw_and_bias_instability_recovered():
    """The simulator's ADIS16405 (white noise + first-order Gauss–Markov bias, σ = datasheet bias stability,
    Tc = 100 s). Its Allan curve has a bump, no flat floor: the analysis fits the Gauss–Markov term and
    reports σ (gauss_markov_sigma), and the IEEE flat-region reading gives 0.617/0.664 = 0.93 σ."""
    from ahrsd.simulation import simulate, open_stream

    rate = 1.0
    block = simulate("static", DAY_S, rate_hz=rate, seed=8)
    errs = open_stream("static", rate_hz=rate, seed=8).errors
    res = analyse_static(block.t_s, block.gyro_rad_s, block.accel_m_s2, block.mag_ut)
    ieee_reading = 0.6174 / FLICKER_FACTOR
    for ax in "xyz":
        g, a, m = res.parameters["gyro"][ax], res.parameters["accel"][ax], res.parameters["mag"][ax]
        assert g.white_noise == pytest.approx(errs.gyro_noise_density_rad_s_rthz, rel=0.10), ax
        assert a.white_noise == pytest.approx(errs.accel_noise_density_m_s2_rthz, rel=0.10), ax
        assert m.white_noise == pytest.approx(errs.mag_noise_density_ut_rthz, rel=0.10), ax
        assert g.gauss_markov_sigma == pytest.approx(errs.gyro_bias_instability_rad_s, rel=0.10), ax
        assert a.gauss_markov_sigma == pytest.approx(errs.accel_bias_instability_m_s2, rel=0.10), ax
        assert g.bias_instability == pytest.approx(ieee_reading * errs.gyro_bias_instability_rad_s, rel=0.10), ax
        assert 50 < g.gauss_markov_tau_s < 200
        # The magnetometer has white noise only: nothing above it.
        assert m.gauss_markov_sigma is None or m.gauss_markov_sigma < 0.2 * m.white_noise


def _params(white: float, std: float) -> NoiseParameters:
    return NoiseParameters(white, None, None, None, None, 0.0, 1.0, std)


def test_kalman_tuning_reproduces_thesis_eq_6_1_and_6_2():
    """Thesis eq. 6-1: ARW 0.05, 0.05, 0.06 °/√s → Q = diag(6.854e-6, 6.854e-6, 9.870e-6, ×1/100 …);
    eq. 6-2: R from the output std (mag first, then accel)."""
    arw = [math.radians(v) for v in (0.05, 0.05, 0.06)]      # thesis Table 6-4
    mag_std = [0.74, 0.66, 0.52]                              # thesis eq. 6-2 (units as printed)
    acc_std = [3.65, 3.44, 3.72]
    res = AllanResult(
        1.0, 1.0, np.array([1.0]), {},
        {"gyro": {ax: _params(v, 0.0) for ax, v in zip("xyz", arw)},
         "mag": {ax: _params(0.0, v) for ax, v in zip("xyz", mag_std)},
         "accel": {ax: _params(0.0, v) for ax, v in zip("xyz", acc_std)}},
    )
    k = kalman_tuning(res)
    np.testing.assert_allclose(k["Q_diag"], [6.854e-6, 6.854e-6, 9.870e-6, 6.854e-8, 6.854e-8, 9.870e-8], rtol=1e-3)
    np.testing.assert_allclose(k["R_diag"], [0.5476, 0.4356, 0.2704, 13.3225, 11.8336, 13.8384], rtol=1e-9)


def test_noise_file_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    n = 4000
    res = analyse_static(np.arange(n) / 10.0, gyro_rad_s=rng.normal(size=(n, 3)) * 0.01)
    path = save_noise_parameters(res, tmp_path / "noise.json")
    doc = load_noise_parameters(path)
    assert doc["gyro"]["x"]["white_noise"] == pytest.approx(res.parameters["gyro"]["x"].white_noise)
    assert len(doc["kalman"]["Q_diag"]) == 6
    (tmp_path / "other.json").write_text('{"format": "something"}')
    with pytest.raises(ValueError, match="not an ahrsd noise"):
        load_noise_parameters(tmp_path / "other.json")


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="too short"):
        analyse_static(np.arange(5.0), gyro_rad_s=np.zeros((5, 3)))
    with pytest.raises(ValueError, match="no sensor data"):
        analyse_static(np.arange(100.0))
    with pytest.raises(ValueError, match="non-finite"):
        allan_deviation(np.array([1.0] * 20 + [math.nan]), 1.0)


def test_a_few_invalid_samples_do_not_break_the_analysis():
    rng = np.random.default_rng(2)
    x = rng.normal(size=(5000, 3))
    x[100] = math.nan
    res = analyse_static(np.arange(5000) / 10.0, gyro_rad_s=x)
    assert res.parameters["gyro"]["x"].white_noise == pytest.approx(1 / math.sqrt(10), rel=0.1)
