"""Which noise terms an Allan curve shows: a weighted fit and a significance test per term (IEEE Std 952).

Model (IEEE Std 952-1997 Annex C, Table C.1), every coefficient ≥ 0, in Allan *variance*:
    σ²(τ) = 3Q²/τ²            quantization Q (angle/velocity quantization, u·s)
          + N²/τ              white noise N (ARW / VRW, u/√Hz)
          + (0.664·B)²        flicker floor, bias instability B (u): 2·ln2/π = 0.664² (Table B.1)
          + K²·τ/3            rate random walk K (u/√s)
          + R²·τ²/2           rate ramp R (u/s)
          + σ_gm²·GM(τ; Tc)   first-order Gauss–Markov bias σ_gm, Tc (Annex C.6; an exponentially
                              correlated bias: a bump, no floor)

The fit uses the octave-spaced points of the curve (τ doubling) and treats each point's Allan variance as
σ²·χ²(edf)/edf, with the equivalent degrees of freedom of the overlapping estimator for the noise type that
the model says dominates there (`adev.edf_overlapping`): the maximum-likelihood fit is an iteratively
reweighted NNLS (weights edf/σ⁴_model), its deviance the likelihood-ratio statistic. The estimate at 2τ reuses
the data of τ, so neighbouring octave points are correlated: the deviance (and the information) is halved,
counting one independent point per two octaves. Each term is kept only if
  1. significance: adding it lowers the deviance by more than the 0.1 % point of χ²(k) (k = 1, or 2 for
     Gauss–Markov, whose Tc is fitted too), both when it is added (forward) and given all the other kept terms
     (backward); a flicker floor and a rate ramp are tested beside a rate random walk, a Gauss–Markov bump
     beside a flicker floor (TESTED_BESIDE): a term is never read from a shape the other terms explain;
  2. it is seen: it is the largest term of the fitted model over at least an octave of τ, starting at a τ with
     at least MIN_CLUSTERS independent clusters (IEEE Std 952 C.2: relative error 1/√(2(K−1)) ≈ 32 % for
     K = 6 clusters), so a term is never carried by the last, scattered points or hidden under others.
  3. where a kept term has a non-nested alternative (ALTERNATIVES: a Gauss–Markov bump for a flicker floor or a
     rate random walk, and back), the model reached by the swap is fitted too, and kept if its terms pass 1 and 2
     and its Akaike criterion (deviance + 2 per fitted parameter) is the lower: the nested tests cannot separate
     two models that differ by a swap.
A term that fails is reported as not seen, with the 2σ upper bound from the deviance profile, the smallest
value this recording would show, and the recording length (or, for quantization, the sample rate) at which
one as large as the bound would dominate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property, lru_cache

import numpy as np

from .adev import AllanCurve, edf_by_alpha
from .covariance import avar_covariance
from .irls import SLOPE_STEP, model_and_edf, weighted_system_at
from ..report import sig_figs

FLICKER_FACTOR = math.sqrt(2.0 * math.log(2.0) / math.pi)  # 0.6643, IEEE Std 952-1997 Table B.1
TERMS = ("quantization", "white", "flicker", "rate_random_walk", "rate_ramp", "gauss_markov")
MIN_CLUSTERS = 6.0
SIGNIFICANCE_P = 1e-3
DELTA_CHI2 = {1: 10.83, 2: 13.82}   # χ²(k) at 1 − SIGNIFICANCE_P (scipy.stats.chi2.isf(1e-3, k))
UPPER_BOUND_SIGMAS = 2.0
IRLS_ITERATIONS = 6
OCTAVE_CORRELATION = 0.5
GM_TC_RANGE = (2.0, 1.0 / 8.0)   # Tc searched from 2·τ_min to τ_max/8 (see fit_terms)


def gauss_markov_avar(taus: np.ndarray, corr_time_s: float) -> np.ndarray:
    """Allan variance of a unit-variance first-order Gauss–Markov process with correlation time Tc:
    σ²(τ) = (2Tc/τ)·[1 − Tc/(2τ)·(3 − 4e^(−τ/Tc) + e^(−2τ/Tc))]  (IEEE Std 952 Annex C.6)."""
    x = np.asarray(taus, dtype=np.float64) / corr_time_s
    small = x < 1e-3   # the bracket cancels for τ ≪ Tc: its Taylor series 2x/3 − x²/2 instead
    out = np.empty_like(x)
    xs = x[~small]
    out[~small] = (2.0 / xs) * (1.0 - (3.0 - 4.0 * np.exp(-xs) + np.exp(-2.0 * xs)) / (2.0 * xs))
    xt = x[small]
    out[small] = (2.0 / 3.0) * xt - 0.5 * xt**2
    return out


def term_basis(name: str, taus: np.ndarray, corr_time_s: float | None = None, white_deficit_s: float = 0.0) -> np.ndarray:
    """Allan variance of the term per unit coefficient (the coefficient is 3Q², N², (0.664B)², K²/3, R²/2, σ²).
    white_deficit_s: D of a sensor filter, which makes white noise 1/τ − D/τ² (correlation)."""
    t = np.asarray(taus, dtype=np.float64)
    if name == "quantization":
        return t**-2.0
    if name == "white":
        return np.maximum(1.0 / t - white_deficit_s / t**2, 0.0)
    if name == "flicker":
        return np.ones_like(t)
    if name == "rate_random_walk":
        return t.copy()
    if name == "rate_ramp":
        return t**2.0
    if name == "gauss_markov":
        return gauss_markov_avar(t, corr_time_s)
    raise ValueError(f"unknown noise term {name!r}")


def coefficient_to_value(name: str, coef: float) -> float:
    """The IEEE 952 parameter from its variance coefficient (flicker: B from the fitted floor)."""
    scale = {"quantization": 1.0 / 3.0, "white": 1.0, "flicker": 1.0 / FLICKER_FACTOR**2,
             "rate_random_walk": 3.0, "rate_ramp": 2.0, "gauss_markov": 1.0}[name]
    return math.sqrt(max(coef, 0.0) * scale)


# τ at which IEEE Std 952 reads each straight line off the plot (its value there is the parameter)
READING_TAU_S = {"quantization": math.sqrt(3.0), "white": 1.0, "rate_random_walk": 3.0, "rate_ramp": math.sqrt(2.0)}


@dataclass(frozen=True)
class _Points:
    """The fit's data: octave-spaced points of one axis' curve."""

    taus: np.ndarray
    avar: np.ndarray
    level_n: np.ndarray
    level_m: np.ndarray
    record_s: float
    white_deficit_s: float = 0.0   # a sensor filter's D (correlation): white noise is 1/τ − D/τ²
    white_deficit_sd_s: float = 0.0   # D's 1σ (correlation.deficit_sds_s), carried by _fit_fixed
    fits: dict = field(default_factory=dict, compare=False, repr=False)   # fit_terms' results by term set
    bases: dict = field(default_factory=dict, compare=False, repr=False)   # _stacked_basis' columns by (term, Tc)
    systems: dict = field(default_factory=dict, compare=False, repr=False)   # _system's arrays by (terms, k, Tc)

    @cached_property
    def edf_table(self) -> np.ndarray:
        """edf of every point for every noise type (adev.edf_by_alpha)."""
        return edf_by_alpha(self.level_n, self.level_m)


@dataclass(frozen=True)
class ModelFit:
    """A fitted set of terms: coefficients (variance units), the GM correlation time, the deviance χ²
    (the coefficients' 1σ: coefficient_sigma)."""

    terms: tuple[str, ...]
    coef: np.ndarray
    corr_time_s: float | None
    chi2: float
    white_deficit_s: float = 0.0   # as _Points.white_deficit_s

    def contribution(self, name: str, taus: np.ndarray) -> np.ndarray:
        if name not in self.terms:
            return np.zeros_like(np.asarray(taus, dtype=np.float64))
        return self.coef[self.terms.index(name)] * term_basis(name, taus, self.corr_time_s, self.white_deficit_s)

    def avar(self, taus: np.ndarray) -> np.ndarray:
        t = np.asarray(taus, dtype=np.float64)
        out = np.zeros_like(t)
        for name in self.terms:
            out = out + self.contribution(name, t)
        return out

    def edf(self, taus: np.ndarray, level_n: np.ndarray, level_m: np.ndarray) -> np.ndarray:
        """Equivalent degrees of freedom per point for the noise type the model says dominates there."""
        t = np.asarray(taus, dtype=np.float64)
        stacked = np.column_stack([term_basis(name, _with_slope_taus(t), self.corr_time_s, self.white_deficit_s) for name in self.terms])
        return model_and_edf(stacked, self.coef, edf_by_alpha(level_n, level_m))[1]


def _with_slope_taus(taus: np.ndarray) -> np.ndarray:
    """τ, then τ·(1 + SLOPE_STEP), then τ/(1 + SLOPE_STEP): where irls.model_and_edf wants the basis."""
    return np.concatenate([taus, taus * (1 + SLOPE_STEP), taus / (1 + SLOPE_STEP)])


def octave_points(curve: AllanCurve, axis: int) -> _Points:
    """The points of the curve whose cluster size (in samples) is a power of two."""
    m_samples = curve.taus_s / curve.taus_s[0] * 1.0
    log2 = np.log2(m_samples)
    pick = np.abs(log2 - np.round(log2)) < 1e-9
    return _Points(curve.taus_s[pick], curve.adev[pick, axis] ** 2, curve.level_n[pick], curve.level_m[pick],
                   curve.record_s)


@lru_cache(maxsize=1)
def _nnls_solver():
    """scipy's NNLS routine. From scipy 1.16 `scipy.optimize.nnls` checks its arguments (finite, 2-D, shapes) and
    calls the compiled `_slsqplib.nnls(A, b, maxiter)`; the fit calls it a few hundred thousand times on a system
    weighted_system has just built (C-ordered float64 of matching shapes), where the checks cost three times the
    solve (weighted_system raises where the finite check would). The same routine is called, so the coefficients
    are the same bits. `_slsqplib` is scipy's private module: where it is missing, or where it no longer answers a
    small problem exactly as the public function does (a scipy release that changed it), the public function."""
    from scipy.optimize import nnls

    def public(a: np.ndarray, b: np.ndarray, maxiter: int) -> np.ndarray:
        return nnls(a, b, maxiter=maxiter)[0]

    try:
        from scipy.optimize._slsqplib import nnls as compiled
    except ImportError:
        return public

    def solve(a: np.ndarray, b: np.ndarray, maxiter: int) -> np.ndarray:
        x, _, info = compiled(a, b, maxiter)
        if info == 3:   # as scipy.optimize.nnls
            raise RuntimeError("Maximum number of iterations reached.")
        return x

    probe_a = np.array([[1.0, 2.0], [3.0, 1.0], [0.5, 4.0]])
    probe_b = np.array([1.0, -2.0, 3.0])
    try:
        same = np.array_equal(solve(probe_a, probe_b, 100), public(probe_a, probe_b, 100))
    except Exception:     # a changed signature or return: any failure of the private call means "not usable"
        same = False
    return solve if same else public


def _nnls_at_model(basis: np.ndarray, target: np.ndarray, model: np.ndarray, floor: np.ndarray, edf: np.ndarray,
                   sigma: np.ndarray) -> np.ndarray:
    """NNLS of (basis, target) with rows weighted 1 / sigma (irls.weighted_system's unit-max columns, then
    _nnls_solver), sigma[:n] = max(model, floor)·√(2/edf) (irls.weighted_system_at)."""
    a, yw, scale = weighted_system_at(basis, target, model, floor, edf, sigma)
    return _nnls_solver()(a, yw, 500) / scale


def _stacked_basis(pts: _Points, terms: tuple[str, ...], tc: float | None) -> np.ndarray:
    """term_basis of each term (columns) at _with_slope_taus(pts.taus) (rows), for irls.model_and_edf;
    each column computed once per (term, Tc)."""
    keys = [(name, tc if name == "gauss_markov" else None) for name in terms]   # only GM depends on Tc
    for name, key in zip(terms, keys):
        if key not in pts.bases:
            pts.bases[key] = term_basis(name, _with_slope_taus(pts.taus), tc, pts.white_deficit_s)
    return np.column_stack([pts.bases[key] for key in keys])


def _system(pts: _Points, all_terms: tuple[str, ...], k: int, tc: float | None):
    """What _fit_fixed's iterations read and never change, once per (terms, fitted count k, Tc) (a deviance
    profile fits the same system some 50 times): the basis at _with_slope_taus (model_and_edf's `stacked`), the
    basis of the k fitted terms at the points (NNLS's), and whether the white term's shape is carried. With it,
    its nuisance as two non-negative columns (+v, −v) of both, and the penalty as one more row of NNLS's."""
    key = (all_terms, k, tc)
    if key not in pts.systems:
        n = len(pts.taus)
        stacked = _stacked_basis(pts, all_terms, tc)
        basis = np.ascontiguousarray(stacked[:n, :k])
        shape = pts.white_deficit_sd_s > 0 and "white" in all_terms
        if shape:
            v = _with_slope_taus(pts.taus) ** -2.0
            stacked = np.column_stack([stacked, v, -v])
            basis = np.vstack([np.column_stack([basis, v[:n], -v[:n]]),
                               np.concatenate([np.zeros(k), [1.0, -1.0]])])
        pts.systems[key] = (stacked, basis, shape)
    return pts.systems[key]


def _fit_fixed(pts: _Points, terms: tuple[str, ...], tc: float | None, fixed: tuple[str, float] | None = None) -> ModelFit:
    """Iteratively reweighted NNLS: weights 1/(σ²_model·√(2/edf)), edf for the model's local noise type.
    fixed: (term, coefficient) held at that value beside the fitted terms (for a profile of the deviance).
    With white noise in the model and the filter's D read with an uncertainty δD (pts.white_deficit_sd_s), the
    white term's shape N²·(1/τ − D/τ²) is uncertain by N²·δD/τ², a rank-one term in the points' covariance. Its
    equivalent in a fit of independent points (Gaussian marginalisation: (r − u·v)ᵀΣ⁻¹(r − u·v) + u²/s² minimised
    over u gives rᵀ(Σ + s²vvᵀ)⁻¹r) is a coefficient u on v = 1/τ² of either sign, fitted beside the terms with the
    penalty (u/s)², s = N²·δD: the fit returns D − u/N² as the white term's D, and the penalty is in the deviance."""
    all_terms = terms if fixed is None else terms + (fixed[0],)
    n = len(pts.taus)
    k = len(terms)
    stacked, basis, shape = _system(pts, all_terms, k, tc)
    offset = np.zeros_like(pts.avar) if fixed is None else fixed[1] * stacked[:n, len(all_terms) - 1]
    model = pts.avar.copy()
    edf = pts.edf_table[2]   # α = 0 (white rate noise) until the model says otherwise
    coef = np.zeros(k)
    coef_all = np.zeros(len(all_terms) + (2 if shape else 0))   # the fitted terms', the fixed one, the shape's
    if fixed is not None:
        coef_all[len(all_terms) - 1] = fixed[1]
    target, floor = pts.avar - offset, 1e-3 * pts.avar
    sigma = np.empty(n + 1 if shape else n)
    if shape:
        target = np.append(target, 0.0)   # the penalty's row
        white = all_terms.index("white")
        c_white = fixed[1] if fixed is not None and fixed[0] == "white" else float(pts.avar[0] * pts.taus[0])
    u, s_u = 0.0, 1.0
    for _ in range(IRLS_ITERATIONS):
        if shape:
            s_u = max(c_white, 1e-300) * pts.white_deficit_sd_s
            # the data's rows are counted once per two points (OCTAVE_CORRELATION), the penalty once
            sigma[n] = s_u * math.sqrt(OCTAVE_CORRELATION)
        # The model's own value sets the weight (a low measured point must not get a high weight); floored so
        # a term the model lacks cannot make a point's weight infinite: σ = max(model, floor)·√(2/edf).
        solved = _nnls_at_model(basis, target, model, floor, edf, sigma)
        coef = solved[:k]
        coef_all[:k] = coef
        if shape:
            coef_all[-2:] = solved[k:]
            u = float(solved[k] - solved[k + 1])
            c_white = float(coef_all[white])
        model, edf = model_and_edf(stacked, coef_all, pts.edf_table)
    ref = np.maximum(model, floor)
    # Deviance of the χ²(edf) likelihood of each point, σ̂²·edf/σ² ~ χ²(edf): the likelihood-ratio statistic
    # (≈ the Gaussian χ² near the model, but a high point of few degrees of freedom costs what it should).
    # The estimate at 2τ is built from the same data as at τ (its clusters are pairs of τ's), so neighbouring
    # octave points are correlated: they are counted as one independent point per two (OCTAVE_CORRELATION).
    ratio = pts.avar / ref
    chi2 = OCTAVE_CORRELATION * float(np.sum(edf * (ratio - 1.0 - np.log(ratio))))
    deficit = pts.white_deficit_s
    if shape:
        chi2 += (u / s_u) ** 2
        deficit = pts.white_deficit_s - (u / c_white if c_white > 0 else 0.0)
    return ModelFit(terms, coef, tc, chi2, deficit)


def profile_upper_bound(pts: _Points, fit: ModelFit, name: str, delta: float) -> float:
    """Upper confidence bound on a term's coefficient from the deviance profile: the value, held fixed beside
    the terms of `fit` (refitted), at which the deviance exceeds the best one with the term free by `delta`
    (4 for 2σ; the likelihood-ratio interval, right for the skewed χ² of few-cluster points)."""
    free = fit_terms(pts, fit.terms + (name,))
    best = free.chi2
    c_hat = float(free.coef[free.terms.index(name)])
    per_unit = pts.avar / term_basis(name, pts.taus, fit.corr_time_s, pts.white_deficit_s)
    hi = float(np.max(per_unit))
    excess = lambda c: _fit_fixed(pts, fit.terms, fit.corr_time_s, (name, c)).chi2 - best - delta  # noqa: E731
    if excess(hi) < 0:
        return hi
    lo = max(c_hat, float(np.min(per_unit)) * 1e-9)
    if excess(lo) >= 0:
        return lo
    for _ in range(50):   # bisection on log c
        mid = math.sqrt(lo * hi)
        lo, hi = (lo, mid) if excess(mid) >= 0 else (mid, hi)
    return hi


def fit_terms(pts: _Points, terms: tuple[str, ...]) -> ModelFit:
    """Fit the given terms; with a Gauss–Markov term, its Tc is searched (4 per octave) for the least χ²,
    between twice the shortest τ and an eighth of the longest (its bump, at 1.89·Tc, and two octaves of its
    1/√τ fall must lie inside the curve: a longer Tc is only a rising slope, which is a rate random walk)."""
    terms = tuple(t for t in TERMS if t in terms)
    if terms not in pts.fits:
        pts.fits[terms] = _fit_searching_tc(pts, terms)
    return pts.fits[terms]


def _fit_searching_tc(pts: _Points, terms: tuple[str, ...]) -> ModelFit:
    if "gauss_markov" not in terms:
        return _fit_fixed(pts, terms, None)
    lo, hi = GM_TC_RANGE[0] * pts.taus[0], GM_TC_RANGE[1] * pts.taus[-1]
    if hi <= lo:
        # the curve is too short to hold a Gauss–Markov bump: the fit is the other terms' alone, and a
        # Gauss–Markov term on its own explains nothing (infinite χ², so the selection never takes it)
        others = tuple(t for t in terms if t != "gauss_markov")
        if not others:
            return ModelFit(terms=(), coef=np.zeros(0), corr_time_s=None, chi2=math.inf)
        return _fit_fixed(pts, others, None)
    grid = np.geomspace(lo, hi, max(2, int(4 * math.log2(hi / lo)) + 1))
    fits = [_fit_fixed(pts, terms, tc) for tc in grid]
    best = min(range(len(fits)), key=lambda i: fits[i].chi2)
    # refine Tc between the neighbours of the best grid point (golden-section on log Tc)
    from scipy.optimize import minimize_scalar

    a, b = math.log(grid[max(best - 1, 0)]), math.log(grid[min(best + 1, len(grid) - 1)])
    if b > a:
        r = minimize_scalar(lambda u: _fit_fixed(pts, terms, math.exp(u)).chi2, bounds=(a, b), method="bounded",
                            options={"xatol": 0.01})
        refined = _fit_fixed(pts, terms, math.exp(r.x))
        if refined.chi2 < fits[best].chi2:
            return refined
    return fits[best]


@lru_cache(maxsize=64)
def _log_grid(tau_lo: float, tau_hi: float) -> np.ndarray:
    """400 log-spaced τ from tau_lo to tau_hi (read-only: shared by every caller with the same range)."""
    grid = np.geomspace(tau_lo, tau_hi, 400)
    grid.flags.writeable = False
    return grid


def dominant_range(fit: ModelFit, name: str, tau_lo: float, tau_hi: float) -> tuple[float, float] | None:
    """The widest τ interval within [tau_lo, tau_hi] over which `name` is the largest term of the model."""
    grid = _log_grid(tau_lo, tau_hi)
    return _widest_run(grid, fit.contribution(name, grid), _largest_other(fit, name, grid))


def _largest_other(fit: ModelFit, name: str, grid: np.ndarray) -> np.ndarray:
    """The largest of the model's other terms at each τ of the grid (0 where there are none)."""
    others = [fit.contribution(t, grid) for t in fit.terms if t != name]
    return np.max(others, axis=0) if others else np.zeros_like(grid)


def _widest_run(grid: np.ndarray, own: np.ndarray, largest_other: np.ndarray) -> tuple[float, float] | None:
    """dominant_range's interval: the widest run of the grid where `own` is positive and above the others."""
    on = (own > largest_other) & (own > 0)
    edges = np.diff(np.concatenate([[0], on.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1   # runs of `on`, inclusive
    if len(starts) == 0:
        return None
    widest = int(np.argmax(grid[ends] / grid[starts]))   # the first of equally wide runs
    return float(grid[starts[widest]]), float(grid[ends[widest]])


def is_seen(fit: ModelFit, name: str, pts: _Points) -> tuple[float, float] | None:
    """The term's τ range if it dominates an octave or more from a τ with ≥ MIN_CLUSTERS clusters, else None."""
    span = dominant_range(fit, name, pts.taus[0], pts.taus[-1])
    if span is None or span[1] < 2.0 * span[0] * (1 - 1e-9) or pts.record_s / span[0] < MIN_CLUSTERS:
        return None
    return span


def _threshold(name: str) -> float:
    return DELTA_CHI2[2 if name == "gauss_markov" else 1]


# Terms tested beside a partner that can mimic them over a short τ range: a flicker floor must be seen beyond
# what a rate random walk explains (a random walk seen through few clusters often bends like a floor; a bias
# instability is never read from a floor the other terms explain), a rate ramp beyond a random walk, a
# Gauss–Markov bump beyond a flicker floor. The partner is dropped again if it is then not needed.
TESTED_BESIDE = {"flicker": "rate_random_walk", "rate_ramp": "rate_random_walk", "gauss_markov": "flicker"}


def select_terms(pts: _Points) -> ModelFit:
    """Forward selection by the largest significant χ² drop, then backward elimination (see module doc), from the
    single term that fits best and from white noise; the better of the two. A greedy path can end where no single
    added term is seen: beside a sensor filter the fit starts a few octaves up, where white noise dominates only
    its first octaves and a strong Gauss–Markov bump the rest; a flicker floor fits that better than either alone,
    and then neither white noise nor the bump is seen beside it."""
    singles = [fit_terms(pts, (t,)) for t in TERMS]
    best_single = min(singles, key=lambda f: f.chi2)
    found = _select_from(pts, best_single)
    if best_single.terms != ("white",):
        from_white = _select_from(pts, fit_terms(pts, ("white",)))
        if from_white.chi2 < found.chi2:
            found = from_white
    return _better_alternative(pts, found)


# Terms that can stand in for each other over a short τ range and are not nested: a Gauss–Markov bump whose Tc is
# a few times the shortest fitted τ looks, over the τ the fit sees, like a flicker floor (and is tested beside one,
# TESTED_BESIDE), so where the nested test cannot tell them apart the floor was kept, and its Kalman Q.
ALTERNATIVES = (("flicker", "gauss_markov"), ("rate_random_walk", "gauss_markov"))


def _parameter_count(fit: ModelFit) -> int:
    return len(fit.terms) + (1 if "gauss_markov" in fit.terms else 0)   # Tc is fitted too


def _aic(fit: ModelFit) -> float:
    """Akaike's criterion on the fit's (halved) deviance: the comparison of non-nested models by their likelihood,
    each fitted parameter costing 2 (Akaike 1974; Burnham & Anderson, Model Selection, 2002, ch. 2)."""
    return fit.chi2 + 2.0 * _parameter_count(fit)


def _all_seen_and_significant(fit: ModelFit, pts: _Points) -> bool:
    """Every term of `fit` is seen and significant given the others (what _select_from's backward step asks)."""
    for name in fit.terms:
        if not is_seen(fit, name, pts):
            return False
        if len(fit.terms) > 1:
            without = fit_terms(pts, tuple(t for t in fit.terms if t != name))
            if without.chi2 - fit.chi2 <= _threshold(name):
                return False
    return True


def _better_alternative(pts: _Points, found: ModelFit) -> ModelFit:
    """The selected model, or the one reached by replacing a kept term with its non-nested alternative
    (ALTERNATIVES) and selecting again from there (_select_from: the other terms may change with it), where that
    model is as acceptable (every term seen and significant, the replaced term not back) and has the lower Akaike
    criterion. The nested tests cannot separate two models that differ by a swap, so their likelihoods decide."""
    best = found
    for a, b in ALTERNATIVES:
        for old, new in ((a, b), (b, a)):
            if old not in found.terms or new in found.terms:
                continue
            swapped = _select_from(pts, fit_terms(pts, tuple(t for t in found.terms if t != old) + (new,)))
            if old not in swapped.terms and _all_seen_and_significant(swapped, pts) and _aic(swapped) < _aic(best):
                best = swapped
    return best


def _select_from(pts: _Points, current: ModelFit) -> ModelFit:
    changed, rounds = True, 0
    while changed and rounds < 4 * len(TERMS):   # a term dropped and re-added forever cannot hang it
        changed, rounds = False, rounds + 1
        best = None
        for name in TERMS:
            if name in current.terms:
                continue
            base = current
            partner = TESTED_BESIDE.get(name)
            if partner is not None and partner not in current.terms:
                base = fit_terms(pts, current.terms + (partner,))
            trial = fit_terms(pts, base.terms + (name,))
            gain = base.chi2 - trial.chi2
            if gain > _threshold(name) and is_seen(trial, name, pts) and (best is None or gain > best[0]):
                best = (gain, trial)
        if best is not None:
            current, changed = best[1], True
        # backward: drop the least needed term that is no longer significant or no longer seen
        while len(current.terms) > 1:
            worst = None
            for name in current.terms:
                without = fit_terms(pts, tuple(t for t in current.terms if t != name))
                gain = without.chi2 - current.chi2
                weak = gain <= _threshold(name) or not is_seen(current, name, pts)
                if weak and (worst is None or gain < worst[0]):
                    worst = (gain, without)
            if worst is None:
                break
            current, changed = worst[1], True
    return current


@dataclass(frozen=True)
class TermEstimate:
    """One noise term that the curve shows: its IEEE 952 value, 1σ, the τ range where it dominates, the χ²
    drop that kept it, and where IEEE 952 reads it (reading_tau_s; the line's value there is `value`)."""

    value: float
    uncertainty: float
    tau_range_s: tuple[float, float]
    delta_chi2: float
    reading_tau_s: float | None
    corr_time_s: float | None = None

    def to_dict(self) -> dict:
        return {"value": self.value, "uncertainty": self.uncertainty, "tau_range_s": list(self.tau_range_s),
                "delta_chi2": self.delta_chi2, "reading_tau_s": self.reading_tau_s,
                "corr_time_s": self.corr_time_s}


def coefficient_sigma(fit: ModelFit, pts: _Points) -> np.ndarray:
    """1σ of the fitted coefficients from the covariance of the points' Allan variances (covariance:
    the correlation of neighbouring τ and each point's variance for the fitted noise), propagated through the
    fit's own weighted least squares (the sandwich A Bᵀ W V W B A, A = (Bᵀ W B)⁻¹, W the fit's last weights)."""
    basis = np.column_stack([term_basis(name, pts.taus, fit.corr_time_s, fit.white_deficit_s) for name in fit.terms])
    model = fit.avar(pts.taus)
    edf = fit.edf(pts.taus, pts.level_n, pts.level_m)
    weight = edf / (2.0 * np.maximum(model, 1e-3 * pts.avar) ** 2)
    cov_avar = avar_covariance(fit, pts.taus, pts.level_n, pts.level_m, pts.record_s)
    if not np.all(np.isfinite(cov_avar)):
        return np.full(len(fit.terms), math.inf)
    if "white" in fit.terms and pts.white_deficit_sd_s > 0:
        # the white term's shape, uncertain by N²·δD/τ² (_fit_fixed): a rank-one term in the points' covariance
        v = fit.coef[fit.terms.index("white")] * pts.white_deficit_sd_s / pts.taus**2
        cov_avar = cov_avar + np.outer(v, v)
    bw = basis * weight[:, None]
    a = np.linalg.pinv(basis.T @ bw)
    cov = a @ bw.T @ cov_avar @ bw @ a
    return np.sqrt(np.maximum(np.diag(cov), 0.0))


def term_estimates(fit: ModelFit, pts: _Points) -> dict[str, TermEstimate]:
    """Value (from the fitted coefficient), 1σ (coefficient_sigma) and τ range of every kept term."""
    out = {}
    sigma = coefficient_sigma(fit, pts)
    for i, name in enumerate(fit.terms):
        span = is_seen(fit, name, pts) or dominant_range(fit, name, pts.taus[0], pts.taus[-1])
        if span is None:
            continue
        c, sc = float(fit.coef[i]), float(sigma[i])
        value = coefficient_to_value(name, c)
        rel = 0.5 * sc / c if c > 0 else math.inf       # p ∝ √c
        without = fit_terms(pts, tuple(t for t in fit.terms if t != name)) if len(fit.terms) > 1 else None
        gain = (without.chi2 - fit.chi2) if without is not None else math.inf
        out[name] = TermEstimate(value, value * rel, span, float(gain), READING_TAU_S.get(name),
                                 fit.corr_time_s if name == "gauss_markov" else None)
    return out


def not_seen_report(fit: ModelFit, pts: _Points, name: str, rate_hz: float) -> dict:
    """For a term the curve does not show: the 2σ upper bound the data put on it, and what would show a term
    that large (a recording length, or for quantization a sample rate)."""
    if name == "gauss_markov":
        lo, hi = GM_TC_RANGE[0] * pts.taus[0], GM_TC_RANGE[1] * pts.taus[-1]
        return {"upper_bound": None, "recording_needed_s": None,
                "note": f"no Gauss–Markov bump for correlation times {sig_figs(lo)}…{sig_figs(hi)} s; a recording of "
                        f"≥ {2 * MIN_CLUSTERS * 1.89:.0f}·Tc would show one with a longer Tc"}
    bound_coef = profile_upper_bound(pts, fit, name, UPPER_BOUND_SIGMAS**2)
    bound = coefficient_to_value(name, bound_coef)
    probe = ModelFit(fit.terms + (name,), np.append(fit.coef, bound_coef),
                     fit.corr_time_s, fit.chi2, fit.white_deficit_s)
    out: dict = {"upper_bound": bound, "recording_needed_s": None}
    if bound_coef <= 0:
        out["note"] = "not constrained by this curve"
        return out
    if name == "quantization":
        span = dominant_range(probe, name, 1e-9, pts.taus[-1])
        if span is None:
            out["note"] = "hidden under the other terms at any sample rate"
        else:
            out["sample_rate_needed_hz"] = 2.0 / span[1]
            out["note"] = f"would show at a sample rate ≥ {sig_figs(2.0 / span[1], 4)} Hz if it were this large"
        return out
    limit = detection_limit(fit, pts, name)
    out["detection_limit"] = limit
    span = dominant_range(probe, name, pts.taus[0], 1e9)
    if limit is None or span is None or span[1] < 2.0 * span[0]:
        out["note"] = "hidden under the terms found at every τ, whatever the recording length"
        return out
    need = MIN_CLUSTERS * span[0]
    out["recording_needed_s"] = need
    out["note"] = (f"this recording would show one ≥ {sig_figs(limit)}; one as large as the bound would dominate from "
                   f"τ = {sig_figs(span[0])} s, i.e. in a recording of ≥ {sig_figs(need / 3600)} h")
    return out


def detection_limit(fit: ModelFit, pts: _Points, name: str) -> float | None:
    """The smallest value of a term (not in `fit`) that this curve would show beside the terms found: the
    largest term over an octave from a τ with ≥ MIN_CLUSTERS clusters (bisection on its coefficient)."""
    per_unit = pts.avar / term_basis(name, pts.taus, None, pts.white_deficit_s)   # coefficient alone explaining each point
    # dominant_range of the fit with the term added at `coef`, bisected 80 times: the other terms' largest, and
    # the term's shape, on the grid once (a term the fit already holds keeps its own coefficient, as
    # ModelFit.contribution reads the first of a name)
    grid = _log_grid(pts.taus[0], pts.taus[-1])
    unit = term_basis(name, grid, fit.corr_time_s, fit.white_deficit_s)
    largest_other = _largest_other(fit, name, grid)
    held = fit.coef[fit.terms.index(name)] if name in fit.terms else None

    def shows(coef: float) -> bool:
        span = _widest_run(grid, np.float64(coef if held is None else held) * unit, largest_other)
        return span is not None and span[1] >= 2.0 * span[0] and pts.record_s / span[0] >= MIN_CLUSTERS

    lo, hi = math.log(float(np.min(per_unit)) * 1e-6), math.log(float(np.max(per_unit)) * 1e3)
    if not shows(math.exp(hi)):
        return None
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if shows(math.exp(mid)) else (mid, hi)
    return coefficient_to_value(name, math.exp(hi))


def flicker_reading(fit: ModelFit, pts: _Points) -> tuple[float, float] | None:
    """IEEE Std 952 reading of the bias instability, B = min σ / 0.664, taken on the fitted curve over the τ
    range where the flicker floor is the largest term (never the curve's shortest τ; the raw curve's minimum
    is scattered by its last few clusters). Returns (B, τ of the minimum) or None when flicker is not kept."""
    if "flicker" not in fit.terms:
        return None
    span = is_seen(fit, "flicker", pts)
    if span is None:
        return None
    grid = np.geomspace(max(span[0], pts.taus[1]), span[1], 200)
    sigma = np.sqrt(fit.avar(grid))
    j = int(np.argmin(sigma))
    return float(sigma[j] / FLICKER_FACTOR), float(grid[j])
