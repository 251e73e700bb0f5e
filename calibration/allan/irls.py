"""The per-iteration arithmetic of the Allan-term fit (terms._fit_fixed), compiled (numba): it runs a few
hundred thousand times on vectors of a few dozen points, where numpy's per-call cost would dominate.

The kernels do element by element what the numpy expressions in their docstrings do, in the same order, so
the fit's numbers do not depend on which one ran.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

SLOPE_STEP = 1e-3   # the model's local log-log slope from its values at τ·(1 ± SLOPE_STEP)


@njit(cache=True)
def weighted_system(basis: np.ndarray, y: np.ndarray, w: np.ndarray):
    """The row-weighted least-squares system with unit-max columns, for NNLS:
    a = basis·w[:, None]; scale = max|a| per column (1 where 0); returns (a / scale, y·w, scale).
    Raises ValueError where scipy.optimize.nnls would (asarray_chkfinite): a value of either is not finite."""
    n, k = basis.shape
    a = np.empty((n, k))
    scale = np.zeros(k)
    for r in range(n):
        for i in range(k):
            a[r, i] = basis[r, i] * w[r]
            scale[i] = max(scale[i], abs(a[r, i]))
    for i in range(k):
        if scale[i] == 0.0:
            scale[i] = 1.0
    finite = True
    for r in range(n):
        for i in range(k):
            a[r, i] = a[r, i] / scale[i]
            finite = finite and math.isfinite(a[r, i])
    yw = y * w
    for r in range(n):
        finite = finite and math.isfinite(yw[r])
    if not finite:
        raise ValueError("array must not contain infs or NaNs")
    return a, yw, scale


@njit(cache=True)
def weighted_system_at(basis: np.ndarray, y: np.ndarray, model: np.ndarray, floor: np.ndarray, edf: np.ndarray,
                       sigma: np.ndarray):
    """An IRLS iteration's weights and its system in one call:
    sigma[:n] = np.maximum(model, floor)·np.sqrt(2.0 / edf) (n = len(model); a NaN of either is NaN, as
    np.maximum's; the rows beyond, the penalty's, are the caller's), then weighted_system(basis, y, 1.0 / sigma)."""
    n = model.shape[0]
    for r in range(n):
        ref = model[r] if model[r] >= floor[r] or math.isnan(model[r]) else floor[r]
        if math.isnan(floor[r]):
            ref = floor[r]
        sigma[r] = ref * math.sqrt(2.0 / edf[r])
    w = np.empty(sigma.shape[0])
    for r in range(sigma.shape[0]):
        w[r] = 1.0 / sigma[r]
    return weighted_system(basis, y, w)


@njit(cache=True)
def model_and_edf(stacked: np.ndarray, coef: np.ndarray, edf_table: np.ndarray):
    """The model σ²(τ) = Σ_i coef_i·basis_i(τ) (summed in term order, as ModelFit.avar) and each point's edf for
    the noise type of its local slope μ = d ln σ² / d ln τ (α from μ as adev.alpha_from_slope: −μ − 1
    rounded half to even, clipped to −2…2; μ = −1 where the model is not positive).
    stacked: the basis (columns) at the n points' τ, then at τ·(1 + SLOPE_STEP), then at τ/(1 + SLOPE_STEP)
    (3n rows); edf_table: row α + 2 of adev.edf_by_alpha."""
    n = stacked.shape[0] // 3
    values = np.zeros(3 * n)
    for r in range(3 * n):
        for i in range(stacked.shape[1]):
            values[r] = values[r] + coef[i] * stacked[r, i]
    edf = np.empty(n)
    for r in range(n):
        above, below = values[n + r], values[2 * n + r]
        slope = math.log(above / below) / (2 * math.log1p(SLOPE_STEP)) if above > 0 and below > 0 else -1.0
        alpha = min(2.0, max(-2.0, np.rint(-slope - 1.0)))
        edf[r] = edf_table[int(alpha) + 2, r]
    return values[:n].copy(), edf
