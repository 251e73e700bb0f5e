"""The covariance of the Allan variances at the octave points of a curve, and from it the 1σ of the fitted terms.

Why: the term fit (terms) weights each point by its own χ² confidence (the equivalent degrees of freedom
of the overlapping estimator, NIST SP 1065 Table 5), as if the points were independent. They are not: the
estimate at 2τ is built from the same data as at τ, and at long τ, where a rate random walk dominates and few
clusters remain, neighbouring points move together almost as one. A least-squares fit that treats them as
independent understates the error of the terms read there (Greenhall & Riley, "Uncertainty of stability
variances based on finite differences", PTTI 2003, compute the estimator's variance the same way: as the
variance of a quadratic form of Gaussian data).

How: an overlapping Allan variance is σ̂²(τ) = 1/(2τ²N) Σ_k d_k², d_k = θ(t_k + 2τ) − 2θ(t_k + τ) + θ(t_k) the
second difference of the phase (angle) θ at N cluster starts t_k. For Gaussian data,
    Cov(σ̂²(τ_i), σ̂²(τ_j)) = 2/(4 τ_i² τ_j² N_i N_j) Σ_k Σ_l c_ij(t_k − t_l)²,   c_ij(u) = Cov(d(u; τ_i), d(0; τ_j)),
(Isserlis' theorem), and c_ij follows from the generalised covariance G of the phase of each noise term,
Cov(Σ a θ(x_a), Σ b θ(y_b)) = Σ Σ a b G(x_a − y_b) for combinations that cancel constants and slopes, as the
second differences do (Matheron's intrinsic random functions of order 1):
    white rate noise (θ a Brownian motion)     G(h) = −|h|/2
    rate random walk (θ an integrated one)     G(h) = |h|³/4
    flicker rate noise                         G(h) = h² ln|h| / (4 ln 2)
    first-order Gauss–Markov, correlation Tc   G(h) = −Tc² e^(−|h|/Tc) − Tc·|h|
    quantization (white angle noise)           G(h) = [h = 0] / 3
each for a unit coefficient of terms.term_basis (so 1/(2τ²)·c_ii(0) is that basis: σ²(τ) of the term).
The independent terms add. A rate ramp is deterministic: it shifts d by its mean R·τ², which adds
4·μ_i·μ_j·c_ij to the sum (the mean's cross term in the fourth moment).

The sum over cluster starts is taken exactly where both points are on the same series with few lags (the
first cluster sizes, where the samples' spacing matters), otherwise as the integral over continuous starts
(Gauss–Legendre between the kinks of c_ij), which is what it tends to once τ spans many samples.
The 1σ of the coefficients is then the sandwich of the fit's own weighted least squares (the estimator the
fit uses) around this covariance: Cov(ĉ) = A Bᵀ W V W B A, A = (Bᵀ W B)⁻¹.
"""

from __future__ import annotations

import math

import numpy as np

W_SECOND_DIFFERENCE = np.array([1.0, -2.0, 1.0])
GAUSS_NODES = 16
EXACT_MAX_LAGS = 4096        # same-series pairs with at most this many lags are summed exactly
TAIL_TAUS = 4.0              # flicker and Gauss–Markov covariances decay, not vanish: summed this many τ beyond
_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(GAUSS_NODES)


def phase_covariance(name: str, h: np.ndarray, corr_time_s: float | None = None) -> np.ndarray:
    """Generalised covariance G(h) of the phase for a unit coefficient of the term (module doc)."""
    a = np.abs(np.asarray(h, dtype=np.float64))
    if name == "white":
        return -0.5 * a
    if name == "rate_random_walk":
        return 0.25 * a**3
    if name == "flicker":
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(a > 0, a * a * np.log(np.where(a > 0, a, 1.0)), 0.0) / (4.0 * math.log(2.0))
    if name == "gauss_markov":
        return -corr_time_s**2 * np.exp(-a / corr_time_s) - corr_time_s * a
    if name == "quantization":
        return np.where(a == 0.0, 1.0 / 3.0, 0.0)
    raise ValueError(f"no phase covariance for {name!r}")


def _offsets(tau_i: float, tau_j: float) -> np.ndarray:
    """a·τ_i − b·τ_j for a, b = 0, 1, 2 (flattened row-major), and the weights w_a·w_b."""
    a = np.arange(3.0)
    return (a[:, None] * tau_i - a[None, :] * tau_j).ravel()


_W_PAIRS = np.outer(W_SECOND_DIFFERENCE, W_SECOND_DIFFERENCE).ravel()


def second_difference_covariance(noise: list[tuple[str, float, float | None]], u: np.ndarray, tau_i: float,
                                 tau_j: float, grid_s: float | None = None) -> np.ndarray:
    """c_ij(u) = Cov(d(u; τ_i), d(0; τ_j)) for the noise terms [(name, coefficient, Tc)]. grid_s: the lags and
    τ are multiples of this sample interval (the lags are snapped to it); None for continuous lags, where
    quantization (a spike at zero lag) is left out."""
    args = np.asarray(u, dtype=np.float64)[:, None] + _offsets(tau_i, tau_j)[None, :]
    if grid_s is not None:
        args = np.rint(args / grid_s) * grid_s
    out = np.zeros(args.shape[0])
    for name, coef, tc in noise:
        if coef == 0.0 or (grid_s is None and name == "quantization"):
            continue
        out += coef * (phase_covariance(name, args, tc) @ _W_PAIRS)
    return out


def _integrate(fn, points: np.ndarray) -> float:
    """∫ fn over [points[0], points[-1]], Gauss–Legendre on each interval between the sorted points."""
    p = np.unique(points)
    if len(p) < 2:
        return 0.0
    lo, hi = p[:-1], p[1:]
    half = 0.5 * (hi - lo)
    u = (0.5 * (hi + lo))[:, None] + half[:, None] * _NODES[None, :]
    return float(np.sum(half[:, None] * _WEIGHTS[None, :] * fn(u.ravel()).reshape(u.shape)))


def avar_covariance(fit, taus_s: np.ndarray, level_n: np.ndarray, level_m: np.ndarray, record_s: float) -> np.ndarray:
    """Covariance (n, n) of the overlapping Allan variances at the points (τ, their series' length and cluster
    size, as adev.AllanCurve), for the noise of the fitted model `fit` (terms.ModelFit)."""
    taus = np.asarray(taus_s, dtype=np.float64)
    spacing = taus / np.asarray(level_m, dtype=np.float64)        # the sample interval of each point's series
    n_starts = np.asarray(level_n, dtype=np.float64) - 2.0 * np.asarray(level_m, dtype=np.float64) + 1.0
    noise, ramp = [], 0.0
    for name, coef in zip(fit.terms, fit.coef):
        if name == "rate_ramp":
            ramp = math.sqrt(2.0 * max(float(coef), 0.0))        # R: σ² = R²τ²/2
        else:
            noise.append((name, float(coef), fit.corr_time_s if name == "gauss_markov" else None))
    tc = fit.corr_time_s if "gauss_markov" in fit.terms else None
    slow = any(name in ("flicker", "gauss_markov") for name, _, _ in noise)
    n = len(taus)
    cov = np.empty((n, n))
    for i in range(n):
        for j in range(i, n):
            ti, tj = taus[i], taus[j]
            mean_ij = 4.0 * ramp * ramp * ti * ti * tj * tj    # 4·μ_i·μ_j
            tail = TAIL_TAUS * (ti + tj) + (10.0 * tc if tc else 0.0) if slow else 0.0
            lo, hi = -2.0 * ti - tail, 2.0 * tj + tail           # where c_ij is not (or no longer) zero
            same_series = abs(spacing[i] - spacing[j]) <= 1e-9 * spacing[i]
            if same_series and (hi - lo) / spacing[i] <= EXACT_MAX_LAGS:
                s = spacing[i]
                lags = np.arange(math.floor(lo / s), math.ceil(hi / s) + 1)
                count = np.clip(np.minimum(n_starts[i], n_starts[j] + lags) - np.maximum(0, lags), 0, None)
                c = second_difference_covariance(noise, lags * s, ti, tj, grid_s=s)
                total = float(np.sum(count * (2.0 * c * c + mean_ij * c))) / (n_starts[i] * n_starts[j])
            else:
                len_i, len_j = max(record_s - 2.0 * ti, 0.0), max(record_s - 2.0 * tj, 0.0)
                if len_i <= 0 or len_j <= 0:
                    cov[i, j] = cov[j, i] = math.inf if i == j else 0.0
                    continue

                def integrand(u):
                    c = second_difference_covariance(noise, u, ti, tj)
                    overlap = np.clip(np.minimum(len_i, len_j + u) - np.maximum(0.0, u), 0.0, None)
                    return overlap * (2.0 * c * c + mean_ij * c)

                kinks = np.concatenate([-_offsets(ti, tj), [0.0, len_i - len_j]])
                if tc:   # the exponential of a Gauss–Markov term bends within a few Tc of each kink
                    scales = tc * 2.0 ** np.arange(-3, 6)
                    kinks = np.concatenate([kinks] + [kinks + s for s in scales] + [kinks - s for s in scales])
                if slow:  # the decaying tails, in geometric steps
                    steps = (ti + tj) * 2.0 ** np.arange(0, 8)
                    kinks = np.concatenate([kinks, 2.0 * tj + steps, -2.0 * ti - steps])
                lo, hi = max(lo, -len_j), min(hi, len_i)
                pts = np.concatenate([[lo, hi], kinks[(kinks > lo) & (kinks < hi)]])
                total = _integrate(integrand, pts) / (len_i * len_j)
            cov[i, j] = cov[j, i] = total / (4.0 * ti * ti * tj * tj)
    return cov
