"""Allan-variance analysis: the streaming estimator, its confidence, and the decision of which noise terms a curve
shows, on synthetic records with known terms (tests/allan_noise.py).

Tolerances follow from the record and the ADEV's confidence: a term is checked against
`ieee952_tolerance(T, τ)` = 3 × 1/√(2(K − 1)), the IEEE Std 952-1997 (C.2) relative error of a σ estimate from
K = T/τ independent clusters, taken at the τ where the injected term makes 90 % of the Allan variance (its
IEEE reading τ for the white noise): three standard errors of the single best point. The fit combines several
points, so it is usually well inside this.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import allan_noise as gen
from ahrsd.calibration.allan.analysis import (AllanResult, NoiseParameters, analyse_static, load_noise_parameters,
                                             save_noise_parameters)
from ahrsd.calibration.allan.adev import StreamingAllan, allan_deviation, confidence_interval, edf_overlapping
from ahrsd.calibration.allan.kalman import kalman_tuning
from ahrsd.calibration.allan.terms import FLICKER_FACTOR, TERMS, gauss_markov_avar

DAY_S = 86_400
ARW = math.radians(2.0) / 60.0          # 2 °/√h (ADIS16405 data sheet), rad/√s
BIAS = math.radians(0.007)              # 0.007 °/s (ADIS16405 data sheet)
K_ISSUE = 8.08e-7                       # rad/s/√s


def ieee952_tolerance(record_s: float, tau_s: float, sigmas: float = 3.0) -> float:
    clusters = record_s / tau_s
    return sigmas / math.sqrt(2.0 * (clusters - 1.0))


def gyro_params(x: np.ndarray, rate_hz: float) -> dict[str, NoiseParameters]:
    n = x.shape[0]
    return analyse_static(np.arange(n) / rate_hz, gyro_rad_s=x).parameters["gyro"]


def three_axes(make, n, rate, rng) -> np.ndarray:
    return np.column_stack([make(n, rate, rng) for _ in range(3)])


# ------------------------------------------------------------------------------------------ the estimator


def test_overlapping_allan_variance_matches_the_definition():
    """σ²(τ) = 1/(2τ²(N−2m+1)) Σ (θ_{k+2m} − 2θ_{k+m} + θ_k)², written out with loops on a short series."""
    rng = np.random.default_rng(3)
    x = rng.normal(size=200) + np.linspace(0, 1, 200)
    rate = 10.0
    curve = allan_deviation(x, rate, m=np.array([1, 3, 7, 20]))
    theta = np.concatenate([[0.0], np.cumsum(x)]) / rate
    for tau, value, nt, m in zip(curve.taus_s, curve.adev[:, 0], curve.n_terms, [1, 3, 7, 20]):
        terms = [(theta[k + 2 * m] - 2 * theta[k + m] + theta[k]) ** 2 for k in range(len(x) + 1 - 2 * m)]
        assert nt == len(terms)
        assert tau == pytest.approx(m / rate)
        assert value == pytest.approx(math.sqrt(sum(terms) / (2 * tau * tau * len(terms))), rel=1e-10)
    # Cluster-mean form (IEEE Std 952-1997) for m = 1: ½ mean of squared differences of samples.
    assert curve.adev[0, 0] ** 2 == pytest.approx(0.5 * np.mean(np.diff(x) ** 2), rel=1e-10)


def test_streaming_gives_the_same_curve_whatever_the_chunks():
    rng = np.random.default_rng(4)
    x = rng.normal(size=(50_000, 3)) + 5.0
    whole = allan_deviation(x, 50.0)
    acc = StreamingAllan(50.0, 3)
    start = 0
    for size in [1, 2, 3, 1000, 7, 4096, 333] * 20:
        acc.add(x[start:start + size])
        start += size
    acc.add(x[start:])
    parts = acc.curve()
    np.testing.assert_array_equal(parts.taus_s, whole.taus_s)
    np.testing.assert_array_equal(parts.n_terms, whole.n_terms)
    np.testing.assert_allclose(parts.adev, whole.adev, rtol=1e-9)


def test_adev_agrees_with_allantools():
    """allantools' fully overlapping ADEV on the same data: equal on the samples themselves (cluster sizes ≤ 13),
    and on the decimated levels (starts every 2^j samples) within 1/√edf, the estimator's own 1σ spread."""
    allantools = pytest.importorskip("allantools")
    rng = np.random.default_rng(5)
    rate = 100.0
    x = gen.white(400_000, rate, ARW, rng) + gen.rate_random_walk(400_000, rate, 20 * K_ISSUE, rng)
    curve = allan_deviation(x, rate)
    taus, ref, _, _ = allantools.oadev(x, rate=rate, data_type="freq", taus=curve.taus_s)
    np.testing.assert_allclose(taus, curve.taus_s)
    level0 = curve.level_m == np.round(curve.taus_s * rate)
    np.testing.assert_allclose(curve.adev[level0, 0], ref[level0], rtol=1e-9)
    edf = np.array([allantools.edf_simple(len(x) + 1, t * rate, 0) for t in curve.taus_s])
    assert np.all(np.abs(curve.adev[~level0, 0] / ref[~level0] - 1.0) < 1.0 / np.sqrt(edf[~level0]))


def test_edf_and_confidence_interval_agree_with_allantools():
    allantools = pytest.importorskip("allantools")
    for alpha in (2, 1, 0, -1, -2):
        for n, m in ((1001, 1), (1001, 2), (10_001, 64), (100_001, 10_000)):
            assert edf_overlapping(alpha, n, m) == pytest.approx(max(allantools.edf_simple(n, m, alpha), 1.0), rel=1e-12)
    lo, hi = confidence_interval(np.array([2.0]), np.array([7.5]))
    ref_lo, ref_hi = allantools.confidence_interval(2.0, 7.5)
    assert lo[0] == pytest.approx(ref_lo, rel=1e-9) and hi[0] == pytest.approx(ref_hi, rel=1e-9)


def test_gauss_markov_allan_variance_limits():
    tc = 100.0
    # τ ≫ Tc: like white noise of density² 2σ²Tc; τ ≪ Tc: like a rate random walk, 2τ/(3Tc).
    assert gauss_markov_avar(np.array([1e6]), tc)[0] == pytest.approx(2 * tc / 1e6, rel=1e-3)
    assert gauss_markov_avar(np.array([1e-4]), tc)[0] == pytest.approx(2 / 3 * 1e-4 / tc, rel=1e-3)
    peak = np.max(np.sqrt(gauss_markov_avar(np.geomspace(1, 1e4, 2000), tc)))
    assert peak == pytest.approx(0.6174, abs=2e-3)  # the classic ≈0.62σ bump at τ ≈ 1.9 Tc


# --------------------------------------------------------------------------- terms of known synthetic records


def test_each_terms_threshold_is_the_chi_square_point_of_the_stated_level():
    # A term is kept when its deviance drop passes the 0.1 % point of χ²(k) (k = 1, or 2 for a Gauss–Markov term
    # whose Tc is fitted too): the rate of false terms on white noise that tests/test_allan_chip_filters.py holds
    # rests on these numbers (from scipy, not from the code).
    from scipy.stats import chi2

    from ahrsd.calibration.allan.terms import DELTA_CHI2, SIGNIFICANCE_P

    assert SIGNIFICANCE_P == 1e-3
    for k in (1, 2):
        assert DELTA_CHI2[k] == pytest.approx(chi2.isf(SIGNIFICANCE_P, k), rel=1e-3), k


def test_white_only_reports_white_and_nothing_else():
    rng = np.random.default_rng(10)
    rate, n = 100.0, 360_000        # 1 h
    for ax, p in gyro_params(three_axes(lambda n, r, g: gen.white(n, r, ARW, g), n, rate, rng), rate).items():
        assert set(p.terms) == {"white"}, ax
        assert p.white_noise == pytest.approx(ARW, rel=ieee952_tolerance(n / rate, 1.0)), ax
        assert p.bias_instability is None and p.rate_random_walk is None and p.quantization is None
        assert p.gauss_markov_sigma is None and p.rate_ramp is None
        assert set(p.not_seen) == set(TERMS) - {"white"}
        rrw = p.not_seen["rate_random_walk"]
        assert rrw["upper_bound"] > 0 and rrw["recording_needed_s"] > 0 and rrw["detection_limit"] > 0


def test_white_plus_rate_random_walk():
    rng = np.random.default_rng(11)
    rate, n, k = 1.0, DAY_S, 10 * K_ISSUE
    x = three_axes(lambda n, r, g: gen.white(n, r, ARW, g) + gen.rate_random_walk(n, r, k, g), n, rate, rng)
    tau_cross = math.sqrt(3.0) * ARW / k      # N²/τ = K²τ/3
    for ax, p in gyro_params(x, rate).items():
        assert set(p.terms) == {"white", "rate_random_walk"}, ax
        assert p.white_noise == pytest.approx(ARW, rel=ieee952_tolerance(DAY_S, 1.0)), ax
        assert p.rate_random_walk == pytest.approx(k, rel=ieee952_tolerance(DAY_S, 3 * tau_cross)), ax
        lo, hi = p.terms["rate_random_walk"].tau_range_s
        assert 0.5 * tau_cross < lo < 2 * tau_cross and hi > 8 * tau_cross
        assert p.bias_instability is None


def test_white_plus_flicker():
    rng = np.random.default_rng(20)
    rate, n = 1.0, DAY_S
    x = three_axes(lambda n, r, g: gen.white(n, r, ARW, g) + gen.flicker(n, r, BIAS, g), n, rate, rng)
    assert FLICKER_FACTOR == pytest.approx(0.6643, abs=1e-4)    # IEEE Std 952-1997 Table B.1: √(2 ln2/π)
    floor = 0.6643 * BIAS
    tau90 = 9.0 * (ARW / floor) ** 2             # N²/τ = floor²/9
    # 2 single-point σ (11 %): the fit spans 8 octaves of floor (measured 2.1 % rms, 5.5 % max over 30 seeds)
    tol = ieee952_tolerance(DAY_S, tau90, sigmas=2.0)
    for ax, p in gyro_params(x, rate).items():
        assert set(p.terms) == {"white", "flicker"}, ax
        assert p.white_noise == pytest.approx(ARW, rel=ieee952_tolerance(DAY_S, 1.0)), ax
        assert p.bias_instability == pytest.approx(BIAS, rel=tol), ax
        assert p.terms["flicker"].value == pytest.approx(BIAS, rel=tol), ax
        # read where the floor dominates: past the white noise's crossing, never the shortest τ
        assert p.tau_bias_instability_s > (ARW / floor) ** 2
        assert p.rate_random_walk is None and p.gauss_markov_sigma is None


def test_white_plus_gauss_markov_from_the_simulator():
    """The simulator's ADIS16405: white noise + a first-order Gauss–Markov bias (σ = data-sheet bias stability,
    Tc = 100 s): a bump, no floor, so a Gauss–Markov term and no bias instability."""
    from ahrsd.simulation import open_stream, simulate

    rate = 1.0
    block = simulate("static", DAY_S, rate_hz=rate, seed=8)
    errs = open_stream("static", rate_hz=rate, seed=8).errors
    res = analyse_static(block.t_s, block.gyro_rad_s, block.accel_m_s2, block.mag_ut)
    tol_gm = ieee952_tolerance(DAY_S, 1.89 * 100.0)
    for ax in "xyz":
        g, a, m = res.parameters["gyro"][ax], res.parameters["accel"][ax], res.parameters["mag"][ax]
        assert set(g.terms) == {"white", "gauss_markov"}, ax
        assert g.white_noise == pytest.approx(errs.gyro_noise_density_rad_s_rthz, rel=ieee952_tolerance(DAY_S, 1.0))
        assert a.white_noise == pytest.approx(errs.accel_noise_density_m_s2_rthz, rel=ieee952_tolerance(DAY_S, 1.0))
        assert m.white_noise == pytest.approx(errs.mag_noise_density_ut_rthz, rel=ieee952_tolerance(DAY_S, 1.0))
        assert g.gauss_markov_sigma == pytest.approx(errs.gyro_bias_instability_rad_s, rel=tol_gm), ax
        assert a.gauss_markov_sigma == pytest.approx(errs.accel_bias_instability_m_s2, rel=tol_gm), ax
        assert 100.0 * (1 - 2 * tol_gm) < g.gauss_markov_tau_s < 100.0 * (1 + 2 * tol_gm)
        assert g.bias_instability is None and a.bias_instability is None
        assert set(m.terms) == {"white"}, ax   # the magnetometer has white noise only


def test_white_plus_gauss_markov():
    rng = np.random.default_rng(21)
    rate, n, tc = 1.0, DAY_S, 300.0
    x = three_axes(lambda n, r, g: gen.white(n, r, ARW, g) + gen.gauss_markov(n, r, BIAS, tc, g), n, rate, rng)
    tol = ieee952_tolerance(DAY_S, 1.89 * tc)
    for ax, p in gyro_params(x, rate).items():
        assert set(p.terms) == {"white", "gauss_markov"}, ax
        assert p.gauss_markov_sigma == pytest.approx(BIAS, rel=tol), ax
        assert tc * (1 - 2 * tol) < p.gauss_markov_tau_s < tc * (1 + 2 * tol), ax
        assert p.bias_instability is None


def test_quantization_plus_white():
    rng = np.random.default_rng(30)
    rate, n = 100.0, 360_000
    q = ARW * math.sqrt(0.1 / 3.0)              # crossing 3Q²/τ² = N²/τ at τ = 0.1 s
    x = three_axes(lambda n, r, g: gen.white(n, r, ARW, g) + gen.quantization(n, r, q, g), n, rate, rng)
    tau90 = 3.0 * q * q / (9.0 * ARW * ARW)     # 3Q²/τ² = 9 N²/τ
    for ax, p in gyro_params(x, rate).items():
        assert set(p.terms) == {"quantization", "white"}, ax
        assert p.quantization == pytest.approx(q, rel=ieee952_tolerance(n / rate, tau90)), ax
        assert p.white_noise == pytest.approx(ARW, rel=ieee952_tolerance(n / rate, 1.0)), ax


# ------------------------------------------------------------------------------ a record like the issue's


def _issue_record(hours: float, rate: float, seed: int, gyro_only: bool = False) -> AllanResult:
    """Gyro ARW 2 °/√h + K = 8.08e-7 rad/s/√s, accel VRW 0.2 m/s/√h, magnetometer 0.125 µT per sample; no flicker.
    `gyro_only`: the gyro alone, generated and analysed (the same gyro samples: generated first)."""
    rng = np.random.default_rng(seed)
    n = int(hours * 3600 * rate)
    gyro = three_axes(lambda n, r, g: gen.white(n, r, ARW, g) + gen.rate_random_walk(n, r, K_ISSUE, g), n, rate, rng)
    if gyro_only:
        return analyse_static(np.arange(n) / rate, gyro)
    accel = three_axes(lambda n, r, g: gen.white(n, r, 0.2 / 60.0, g), n, rate, rng) + [0.0, 0.0, -9.81]
    mag = rng.standard_normal((n, 3)) * 0.125 + [20.0, 0.0, 40.0]
    return analyse_static(np.arange(n) / rate, gyro, accel, mag)


def test_a_record_like_the_issue_3_h_at_100_hz():
    """3 h: K dominates only from τ_c = √3·N/K ≈ 1250 s, i.e. T/τ_c ≈ 8.7 clusters: IEEE 952 puts ±26 % (1σ) on
    a σ read there, so K is either found within 2σ of that (and of its own reported 1σ) or reported not seen
    with a 2σ bound above the truth. White within 3 %; no bias instability on any sensor; no other term."""
    res = _issue_record(3.0, 100.0, seed=1)
    tau_c = math.sqrt(3.0) * ARW / K_ISSUE
    one_sigma = ieee952_tolerance(3 * 3600.0, tau_c, sigmas=1.0)
    for ax in "xyz":
        g = res.parameters["gyro"][ax]
        assert g.white_noise == pytest.approx(ARW, rel=0.03), ax
        assert set(g.terms) <= {"white", "rate_random_walk"}, ax
        if g.rate_random_walk is not None:
            assert g.rate_random_walk == pytest.approx(K_ISSUE, rel=2 * one_sigma), ax
            assert abs(g.rate_random_walk - K_ISSUE) < 2 * g.terms["rate_random_walk"].uncertainty, ax
        else:
            assert g.not_seen["rate_random_walk"]["upper_bound"] > K_ISSUE, ax
        assert res.parameters["accel"][ax].white_noise == pytest.approx(0.2 / 60.0, rel=0.03)
        assert res.parameters["mag"][ax].white_noise == pytest.approx(0.125 / 10.0, rel=0.03)
        for sensor in ("gyro", "accel", "mag"):
            assert res.parameters[sensor][ax].bias_instability is None, (sensor, ax)
        for sensor in ("accel", "mag"):
            assert set(res.parameters[sensor][ax].terms) == {"white"}, (sensor, ax)
    assert res.to_json_dict()["kalman"]["gyro_bias_instability_rad_s"] == [None, None, None]


def test_a_record_like_the_issue_but_24_h():
    """24 h (at 10 Hz: the noise is defined by its densities): T/τ_c ≈ 69 clusters, IEEE 952 ±8.6 % (1σ) at τ_c;
    K is found on every axis within 3σ of that (and within the issue's 15 % on this record)."""
    res = _issue_record(24.0, 10.0, seed=2, gyro_only=True)      # only the gyro is read here
    tau_c = math.sqrt(3.0) * ARW / K_ISSUE
    for ax in "xyz":
        g = res.parameters["gyro"][ax]
        assert set(g.terms) == {"white", "rate_random_walk"}, ax
        assert g.white_noise == pytest.approx(ARW, rel=0.03), ax
        assert g.rate_random_walk == pytest.approx(K_ISSUE, rel=ieee952_tolerance(DAY_S, tau_c)), ax
        assert g.rate_random_walk == pytest.approx(K_ISSUE, rel=0.15), ax
        assert g.bias_instability is None


# ----------------------------------------------------------------------------------------- Kalman and files


def _params(white: float | None, std: float, **kw) -> NoiseParameters:
    return NoiseParameters(white, kw.get("b"), kw.get("k"), None, kw.get("tau_b"), 0.0, 1.0, std,
                           kw.get("gm_sigma"), kw.get("gm_tau"))


def test_kalman_tuning_reproduces_the_thesis_q_and_r_when_no_bias_term_is_seen():
    """Worked example, the thesis's tuning: ARW 0.05, 0.05, 0.06 °/√s → Q = diag(6.854e-6, 6.854e-6, 9.870e-6, ×1/100 …);
    R from the output std (mag first, then accel). The ARW/10 bias drive is listed as assumed."""
    arw = [math.radians(v) for v in (0.05, 0.05, 0.06)]      # the thesis's Allan ARW, °/√s
    mag_std = [0.74, 0.66, 0.52]                              # the thesis's R (units as printed)
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
    keys = {a["key"] for a in k["assumed"]}
    assert {f"gyro_bias_drive_rad_s_sqrt_s.{ax}" for ax in "xyz"} <= keys
    assert {f"gyro_bias_instability_rad_s.{ax}" for ax in "xyz"} <= keys
    assert all("data sheet" in a["source"] for a in k["assumed"] if a["key"].startswith("gyro_bias_instability"))
    assert k["gyro_bias_instability_rad_s"] == [None, None, None]


def test_kalman_bias_drive_comes_from_the_terms_found():
    n = 5e-4
    gyro = {"x": _params(n, 0.0, k=2e-6),                        # rate random walk: w_b = K
            "y": _params(n, 0.0, gm_sigma=1e-4, gm_tau=200.0),   # Gauss–Markov: σ·√(2/Tc)
            "z": _params(None, 0.0, b=1e-4, tau_b=500.0)}        # flicker: 0.664·B·√(3/τ_B); white from data sheet
    k = kalman_tuning(AllanResult(1.0, 1.0, np.array([1.0]), {}, {"gyro": gyro}))
    drive = k["gyro_bias_drive_rad_s_sqrt_s"]
    assert drive[0] == pytest.approx(2e-6)
    assert drive[1] == pytest.approx(1e-4 * math.sqrt(2 / 200.0))
    assert drive[2] == pytest.approx(0.6643 * 1e-4 * math.sqrt(3 / 500.0), rel=1e-3)
    assert k["gyro_arw_rad_sqrt_s"][2] == pytest.approx(math.radians(2.0) / 60.0)
    assert k["Q_diag"][3] == pytest.approx((3 * 2e-6) ** 2)
    assert [a["key"] for a in k["assumed"]] == ["gyro_bias_instability_rad_s.x", "gyro_bias_instability_rad_s.y",
                                               "gyro_arw_rad_sqrt_s.z"]
    assert k["gyro_bias_instability_rad_s"] == [None, None, 1e-4]


def test_noise_file_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    n = 4000
    res = analyse_static(np.arange(n) / 10.0, gyro_rad_s=rng.normal(size=(n, 3)) * 0.01)
    path = save_noise_parameters(res, tmp_path / "noise.json")
    doc = load_noise_parameters(path)
    assert doc["gyro"]["x"]["white_noise"] == pytest.approx(res.parameters["gyro"]["x"].white_noise)
    assert doc["gyro"]["x"]["terms"]["white"]["tau_range_s"][0] == pytest.approx(0.1)
    assert doc["gyro"]["x"]["terms"]["flicker"] is None and "flicker" in doc["gyro"]["x"]["not_seen"]
    assert len(doc["curves"]["gyro"]["x"]["adev"]) == len(doc["curves"]["taus_s"])
    assert all(lo < a < hi for lo, a, hi in zip(doc["curves"]["gyro"]["x"]["lower"], doc["curves"]["gyro"]["x"]["adev"],
                                                doc["curves"]["gyro"]["x"]["upper"]))
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
    with pytest.raises(ValueError, match="do not increase"):
        analyse_static(np.zeros(100), gyro_rad_s=np.zeros((100, 3)))


def test_a_few_invalid_samples_do_not_break_the_analysis():
    rng = np.random.default_rng(2)
    x = rng.normal(size=(5000, 3))
    x[100] = math.nan
    res = analyse_static(np.arange(5000) / 10.0, gyro_rad_s=x)
    assert res.parameters["gyro"]["x"].white_noise == pytest.approx(1 / math.sqrt(10), rel=0.1)
    assert res.replaced_samples["gyro"] == 1


# ---------------------------------------------------------------------------------------- the decision rules


def test_a_random_walk_that_bends_like_a_floor_is_not_a_bias_instability():
    """3 h of white + K (the issue's values): on this realization one axis' curve flattens between τ ≈ 160 s
    and 2600 s (found while writing the test), and a free white + flicker fit beats white + K there. A flicker
    floor is kept only when it is significant beyond what a rate random walk explains."""
    rng = np.random.default_rng(205)
    rate, n = 100.0, int(3 * 3600 * 100)
    x = three_axes(lambda n, r, g: gen.white(n, r, ARW, g) + gen.rate_random_walk(n, r, K_ISSUE, g), n, rate, rng)
    for ax, p in gyro_params(x, rate).items():
        assert p.bias_instability is None and "flicker" not in p.terms, ax


def _points_from_model(fit, record_s: float, tau0: float):
    """Octave points lying exactly on a model, with the cluster bookkeeping of a record of record_s."""
    from ahrsd.calibration.allan.terms import _Points

    taus = tau0 * 2.0 ** np.arange(int(math.log2(record_s / 3 / tau0)) + 1)
    n = record_s / tau0
    return _Points(taus, fit.avar(taus), np.full(len(taus), n), taus / tau0, record_s)


def test_a_term_must_dominate_from_enough_clusters():
    from ahrsd.calibration.allan.terms import MIN_CLUSTERS, ModelFit, is_seen

    record_s = 10_000.0
    for start_clusters, seen in ((2 * MIN_CLUSTERS, True), (MIN_CLUSTERS / 2, False)):
        tau_cross = record_s / start_clusters                 # RRW = white at τ_c: K²τ_c/3 = N²/τ_c
        k2_3 = ARW**2 / tau_cross**2
        fit = ModelFit(("white", "rate_random_walk"), np.array([ARW**2, k2_3]), None, 0.0)
        span = is_seen(fit, "rate_random_walk", _points_from_model(fit, record_s, 0.01))
        assert (span is not None) == seen
        if seen:
            assert span[0] == pytest.approx(tau_cross, rel=0.04)   # the 400-point τ grid: 3 % steps


def test_bias_instability_is_never_read_at_the_shortest_tau():
    """Flicker dominating from the first τ, then a random walk: the model's minimum would be the first point."""
    from ahrsd.calibration.allan.terms import ModelFit, flicker_reading

    fit = ModelFit(("flicker", "rate_random_walk"), np.array([1e-8, 1e-12]), None, 0.0)
    pts = _points_from_model(fit, 100_000.0, 1.0)
    b, tau = flicker_reading(fit, pts)
    assert tau >= pts.taus[1]
    assert b == pytest.approx(math.sqrt(1e-8 + 1e-12 * pts.taus[1]) / FLICKER_FACTOR, rel=1e-9)


def test_the_report_gives_every_figure_three_significant_digits():
    """#30: the lead line printed an ARW of 2.00 °/√h as "2" (:.3g drops trailing zeros, so a figure known to
    three digits read as known to one)."""
    from ahrsd.calibration.allan.analysis import summary
    from ahrsd.calibration.report import sig_figs

    assert [sig_figs(v) for v in (2.0, 0.2, 99.96, 4.56e-5, 123456.0)] == ["2.00", "0.200", "100", "4.56e-05",
                                                                           "1.23e+05"]
    n = 20000
    result = analyse_static(np.arange(n) / 819.2, gyro_rad_s=np.random.default_rng(3).normal(0.0, 1e-3, (n, 3)))
    from dataclasses import replace

    gyro = result.parameters["gyro"]
    for axis, arw_deg_sqrt_h in (("x", 2.0), ("y", 0.5)):
        gyro[axis] = replace(gyro[axis], white_noise=arw_deg_sqrt_h / (math.degrees(1.0) * 60.0))
    lead = summary(result)[0]
    assert "ARW (°/√h): x 2.00  y 0.500  z " in lead, lead
