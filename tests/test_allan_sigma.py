"""The reported 1σ of the Allan terms is honest: the covariance of the octave points' Allan variances
(calibration/allan/covariance.py) against NIST SP 1065's equivalent degrees of freedom and against Monte Carlo,
and the white-noise and rate-random-walk 1σ against their errors on held-out synthetic records (z = error/σ:
RMS ≈ 1, about 0.3 % beyond 3σ). The full figures, with the term selection, come from bench/allan_sigma.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import allan_noise as gen
from ahrsd.calibration.allan.adev import allan_deviation, edf_overlapping
from ahrsd.calibration.allan.covariance import avar_covariance, second_difference_covariance
from ahrsd.calibration.allan.terms import ModelFit, fit_terms, gauss_markov_avar, octave_points, term_estimates


def _unit_fit(name: str, corr_time_s: float | None = None) -> ModelFit:
    return ModelFit((name,), np.array([1.0]), corr_time_s, 0.0)


def test_each_terms_phase_covariance_gives_its_allan_variance():
    """1/(2τ²)·Var(d) from the phase covariance is the IEEE Std 952 Allan variance of the term, written out
    here independently (N²/τ, K²τ/3, the flicker floor, 3Q²/τ², and Gauss–Markov from its own formula)."""
    expected = {"white": lambda t: 1.0 / t, "rate_random_walk": lambda t: t, "flicker": lambda t: 1.0,
                "quantization": lambda t: 1.0 / t**2}
    for tau in (1.0, 5.0, 300.0):
        for name, avar in expected.items():
            var_d = second_difference_covariance([(name, 1.0, None)], np.zeros(1), tau, tau, grid_s=1.0)[0]
            assert var_d / (2 * tau * tau) == pytest.approx(avar(tau), rel=1e-12), (name, tau)
        var_d = second_difference_covariance([("gauss_markov", 1.0, 40.0)], np.zeros(1), tau, tau)[0]
        assert var_d / (2 * tau * tau) == pytest.approx(float(gauss_markov_avar(np.array([tau]), 40.0)[0]), rel=1e-9)


@pytest.mark.parametrize("name, alpha, tolerance", [("white", 0, 0.02), ("rate_random_walk", -2, 0.12)])
def test_each_points_variance_matches_the_edf_of_sp1065(name, alpha, tolerance):
    """Var(σ̂²) = 2σ⁴/edf with NIST SP 1065 Table 5's edf (Howe, Allan & Barnes' formulas: exact for white
    noise, an approximation of a few percent for a random walk)."""
    n = 20_000
    m = np.array([1, 2, 5, 13, 64, 512, 2048], dtype=float)   # up to T/10: the simple formulas are for m ≪ N
    cov = avar_covariance(_unit_fit(name), m, np.full(len(m), float(n)), m, float(n))
    avar = m ** (1.0 if name == "rate_random_walk" else -1.0)
    edf = 2 * avar**2 / np.diag(cov)
    nist = np.array([edf_overlapping(alpha, n + 1.0, mi) for mi in m])
    assert edf == pytest.approx(nist, rel=tolerance)


def _white_plus_random_walk(n, rate, white, k, rng, axes):
    return np.column_stack([gen.white(n, rate, white, rng) + gen.rate_random_walk(n, rate, k, rng)
                            for _ in range(axes)])


def test_neighbouring_points_correlate_as_predicted():
    """Monte Carlo: 600 records of white noise + a rate random walk (crossing at 35 s); the sample covariance
    of the octave points' Allan variances (through the streaming estimator) against avar_covariance."""
    rng = np.random.default_rng(7)
    n, rate, white, k = 4096, 1.0, 1.0, math.sqrt(3.0) / 35.0
    rows = []
    for _ in range(150):
        curve = allan_deviation(_white_plus_random_walk(n, rate, white, k, rng, 4), rate)
        rows += [octave_points(curve, axis).avar for axis in range(4)]
    pts = octave_points(curve, 0)
    fit = ModelFit(("white", "rate_random_walk"), np.array([white**2, k * k / 3.0]), None, 0.0)
    predicted = avar_covariance(fit, pts.taus, pts.level_n, pts.level_m, pts.record_s)
    sample = np.cov(np.array(rows).T)
    sd_p, sd_s = np.sqrt(np.diag(predicted)), np.sqrt(np.diag(sample))
    assert sd_s == pytest.approx(sd_p, rel=0.12)
    corr_p = np.diag(predicted / np.outer(sd_p, sd_p), 1)
    corr_s = np.diag(sample / np.outer(sd_s, sd_s), 1)
    assert np.max(np.abs(corr_s - corr_p)) < 0.1, (corr_s, corr_p)
    assert corr_p[-3:].min() > 0.75       # where the random walk dominates, neighbours move almost together


def _z_scores(seed0: int, records: int, n: int, cross_s: float) -> dict[str, np.ndarray]:
    """error/σ of the white noise and K on held-out records (white N = 1 + K crossing at cross_s), fitted with
    both terms (the term selection is bench/allan_sigma.py's: too slow for a unit test)."""
    rate, white = 1.0, 1.0
    k = math.sqrt(3.0) * white / cross_s
    z: dict[str, list] = {"white": [], "rate_random_walk": []}
    for r in range(records):
        rng = np.random.default_rng(seed0 + r)
        curve = allan_deviation(_white_plus_random_walk(n, rate, white, k, rng, 3), rate)
        for axis in range(3):
            pts = octave_points(curve, axis)
            fit = fit_terms(pts, ("white", "rate_random_walk"))
            for name, est in term_estimates(fit, pts).items():
                if est.value > 0:
                    z[name].append((est.value - {"white": white, "rate_random_walk": k}[name]) / est.uncertainty)
    return {name: np.array(v) for name, v in z.items()}


@pytest.mark.parametrize("n, cross_s", [(16_384, 100.0), (8_192, 400.0)])
def test_the_reported_sigma_matches_the_error_on_held_out_records(n, cross_s):
    """120 axes per case; a random walk seen over 160 and over 20 clusters of its crossing τ. An honest 1σ:
    RMS(z) within the sampling spread of 120 values around 1, at most 2 % beyond 3σ (0.3 % expected)."""
    z = _z_scores(9000 + n, 40, n, cross_s)
    for name, values in z.items():
        assert len(values) >= 110, name
        rms = math.sqrt(float(np.mean(values**2)))
        print(f"n {n}, crossing {cross_s:g} s, {name}: error/σ RMS {rms:.2f}, beyond 2σ "
              f"{np.mean(np.abs(values) > 2) * 100:.1f} %, beyond 3σ {np.mean(np.abs(values) > 3) * 100:.1f} %")
        assert 0.8 < rms < 1.25, (name, rms)
        assert np.mean(np.abs(values) > 3) <= 0.02, name


# the chip's default SENS_AVG: two 4-tap averages (a 7-tap Bartlett window), unit gain at zero frequency
BARTLETT = np.convolve(np.ones(4) / 4, np.ones(4) / 4)


def test_a_filters_share_of_white_noise_is_the_deficit_read_from_the_data():
    """The filter lowers white noise's Allan variance to N²(1/τ − D/τ²), D = 1.5·Σ|s|a(s)/Σa(s) over the
    kernel's autocorrelation a: checked against the Allan variance written out from the kernel (the second
    difference of the filtered phase as weights on the white samples), and D read from filtered data."""
    a = np.convolve(BARTLETT, BARTLETT[::-1])
    lags = np.arange(len(a)) - (len(a) - 1) // 2
    deficit = 1.5 * float(np.sum(np.abs(lags) * a) / np.sum(a))
    for m in (16, 40, 333):
        weights = np.convolve(np.concatenate([-np.ones(m), np.ones(m)]), BARTLETT)   # d on unit white samples
        assert float(np.sum(weights**2)) / (2 * m * m) == pytest.approx(1 / m - deficit / m**2, rel=1e-12)
    from ahrsd.calibration.allan.correlation import SampleCorrelation

    rng = np.random.default_rng(12)
    white = rng.normal(size=(300_000, 3))
    correlation = SampleCorrelation()
    correlation.add(np.column_stack([np.convolve(white[:, k], BARTLETT, mode="valid") for k in range(3)]))
    assert correlation.deficits_s(2.0) == pytest.approx(np.full(3, deficit / 2.0), rel=0.03)


def test_a_sensor_filter_does_not_bias_the_white_noise():
    """White noise at 819.2 SPS through the chip's filter, 20 min: N within 3 reported σ on every axis, and
    their mean within 3σ of the mean (a fit of N/√τ alone reads it 1–1.5 % low: 5σ of the mean of three)."""
    from ahrsd.calibration.allan.analysis import analyse_static

    rng = np.random.default_rng(13)
    rate, n, density = 819.2, 1 << 20, 5.8e-4
    x = np.column_stack([np.convolve(gen.white(n + 6, rate, density, rng), BARTLETT, mode="valid") for _ in range(3)])
    errors, sigmas = [], []
    for axis, p in analyse_static(np.arange(n) / rate, gyro_rad_s=x).parameters["gyro"].items():
        est = p.terms["white"]
        print(f"{axis}: white {est.value / density - 1:+.2%} ± {est.uncertainty / density:.2%}")
        assert abs(est.value - density) < 3 * est.uncertainty, axis
        errors.append(est.value - density)
        sigmas.append(est.uncertainty)
    assert abs(np.mean(errors)) < 3 * math.sqrt(np.sum(np.square(sigmas))) / 3
