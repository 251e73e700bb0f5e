"""The Allan-term fit's inner loop (calibration/allan/terms.py's _fit_fixed) calls scipy's compiled NNLS routine without
the public function's argument checks, and reuses each system it builds: the coefficients must be scipy.optimize.nnls's
own bits, its errors must be raised as scipy raises them, and a fit must not depend on which fits ran before it on
the same points."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import nnls

import allan_noise as gen
from ahrsd.calibration.allan.adev import allan_deviation
from ahrsd.calibration.allan.irls import weighted_system, weighted_system_at
from ahrsd.calibration.allan.terms import _fit_fixed, _nnls_solver, octave_points, term_basis

RATE_HZ = 100.0


def _weighted_nnls(basis, y, w):
    """What the fit's NNLS step does (terms._nnls_at_model, with the weights given): the weighted system with
    unit-max columns, solved by the routine terms._nnls_solver picks, scaled back."""
    a, yw, scale = weighted_system(basis, y, w)
    return _nnls_solver()(a, yw, 500) / scale


def _points(deficit_sd_s: float = 0.0):
    """One axis' octave points of white noise plus a Gauss–Markov bias; with deficit_sd_s, as beside a sensor
    filter whose D (0.05 s) is read with that 1σ (the fit then carries the white term's shape)."""
    rng = np.random.default_rng(3)
    n = int(600 * RATE_HZ)
    x = np.column_stack([gen.white(n, RATE_HZ, 1e-3, rng) + gen.gauss_markov(n, RATE_HZ, 2e-4, 5.0, rng)
                         for _ in range(3)])
    pts = octave_points(allan_deviation(x, RATE_HZ), 0)
    if deficit_sd_s:
        pts = type(pts)(pts.taus, pts.avar, pts.level_n, pts.level_m, pts.record_s, 0.05, deficit_sd_s)
    return pts


def test_the_solver_returns_scipys_nnls_coefficients_bit_for_bit():
    pts = _points()
    rng = np.random.default_rng(4)
    taus = pts.taus
    for terms in (("white",), ("white", "flicker"), ("quantization", "white", "rate_random_walk", "rate_ramp"),
                  ("white", "gauss_markov")):
        basis = np.column_stack([term_basis(t, taus, 3.0) for t in terms])
        for _ in range(20):
            w = 1.0 / (pts.avar * rng.uniform(0.2, 5.0, len(taus)))
            y = pts.avar * rng.uniform(0.5, 2.0, len(taus))
            a, yw, scale = weighted_system(basis, y, w)
            expected = nnls(a, yw, maxiter=500)[0] / scale
            assert np.array_equal(_weighted_nnls(basis, y, w), expected), terms


def test_the_iterations_weights_are_numpys_bit_for_bit():
    """weighted_system_at builds the system the fit built with numpy: σ = np.maximum(model, floor)·np.sqrt(2/edf)
    on the points (the floor where the model is below it, a NaN of either a NaN), the penalty's row as given."""
    rng = np.random.default_rng(7)
    basis = rng.uniform(0.1, 2.0, (13, 3))
    for _ in range(50):
        model = rng.uniform(0.0, 2.0, 12) * 10.0 ** rng.integers(-12, -6)
        floor = 1e-3 * model * rng.uniform(0.1, 2000.0, 12)      # about half the points below their floor
        edf = rng.uniform(0.5, 300.0, 12)
        y = rng.uniform(0.0, 1.0, 13)
        sigma = np.empty(13)
        sigma[12] = rng.uniform(0.1, 3.0)
        expected = np.append(np.maximum(model, floor) * np.sqrt(2.0 / edf), sigma[12])
        got = weighted_system_at(basis, y, model, floor, edf, sigma)
        for g, e in zip(got, weighted_system(basis, y, 1.0 / expected)):
            assert np.array_equal(g, e)
        assert np.array_equal(sigma, expected)
    for bad in ("model", "floor"):
        args = {"model": np.ones(12), "floor": np.full(12, 0.5)}
        args[bad][4] = np.nan
        with pytest.raises(ValueError, match="infs or NaNs"):
            weighted_system_at(basis, np.ones(13), args["model"], args["floor"], np.ones(12), np.ones(13))


def test_the_solver_refuses_what_scipy_refuses():
    basis = np.column_stack([np.ones(6), np.arange(1.0, 7.0)])
    y = np.arange(6.0)
    for bad in (np.inf, np.nan):
        w = np.ones(6)
        w[2] = bad
        with pytest.raises(ValueError, match="infs or NaNs"):
            nnls(basis * w[:, None], y * w, maxiter=500)
        with pytest.raises(ValueError, match="infs or NaNs"):
            _weighted_nnls(basis, y, w)
    # too few iterations: scipy's RuntimeError
    rng = np.random.default_rng(5)
    a, b = rng.normal(size=(12, 6)), rng.normal(size=12)
    with pytest.raises(RuntimeError):
        nnls(a, b, maxiter=1)
    with pytest.raises(RuntimeError):
        _nnls_solver()(a, b, 1)


@pytest.mark.parametrize("deficit_sd_s", [0.0, 0.01])
def test_a_fit_does_not_depend_on_the_fits_before_it_on_the_same_points(deficit_sd_s):
    fresh = {tc: _fit_fixed(_points(deficit_sd_s), ("white", "gauss_markov"), tc) for tc in (1.0, 4.0)}
    shared = _points(deficit_sd_s)
    _fit_fixed(shared, ("white", "flicker"), None)
    _fit_fixed(shared, ("white",), None, ("flicker", 1e-9))
    for tc in (1.0, 4.0):
        fit = _fit_fixed(shared, ("white", "gauss_markov"), tc)
        assert (fit.chi2, fit.white_deficit_s) == (fresh[tc].chi2, fresh[tc].white_deficit_s), tc
        assert np.array_equal(fit.coef, fresh[tc].coef), tc
    # the deviance profile's fits: the fixed term's value moves, the system it is fitted in is the same
    for c in (1e-10, 1e-8):
        assert _fit_fixed(shared, ("white",), None, ("flicker", c)).chi2 == \
            _fit_fixed(_points(deficit_sd_s), ("white",), None, ("flicker", c)).chi2
    _fit_fixed(shared, ("flicker",), None, ("white", 1e-6))   # the fixed term is the shape's white term
    assert _fit_fixed(shared, ("flicker",), None, ("white", 2e-6)).chi2 == \
        _fit_fixed(_points(deficit_sd_s), ("flicker",), None, ("white", 2e-6)).chi2


def test_a_private_routine_that_answers_differently_is_not_used(monkeypatch):
    """A scipy release that changes `_slsqplib.nnls` (its signature, its return) must not break the fit: the solver
    falls back to the public function. Simulated by a private routine that answers with a different tuple."""
    import scipy.optimize._slsqplib as private

    from ahrsd.calibration.allan import terms as allan_terms

    monkeypatch.setattr(private, "nnls", lambda a, b, maxiter: (np.zeros(a.shape[1]),))
    allan_terms._nnls_solver.cache_clear()
    try:
        rng = np.random.default_rng(6)
        a, b = rng.normal(size=(10, 4)), rng.normal(size=10)
        assert np.array_equal(allan_terms._nnls_solver()(a, b, 500), nnls(a, b, maxiter=500)[0])
    finally:
        allan_terms._nnls_solver.cache_clear()
