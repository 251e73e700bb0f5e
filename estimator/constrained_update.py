"""The scalar Kalman update with a constrained gain, shared by both filters (numba).

A measurement that must not move some error-state components (the magnetometer never moves the tilt, the
accelerometer never the heading) gets a gain forced to zero on them. The optimal gain's covariance update
P − K S Kᵀ is then wrong; the Joseph form P ← (I − K h) P (I − K h)ᵀ + K r Kᵀ holds for any gain and, with
u = P hᵀ and s = h P hᵀ + r, expands to P ← P − K uᵀ − u Kᵀ + s K Kᵀ (P. S. Maybeck, Stochastic Models,
Estimation and Control, vol. 1, eq. 5-61; D. Simon, Optimal State Estimation, 2006, eq. 7.50 for
constrained gains). `zero_mask`: bit i set = the gain of error-state component i is zero.

Three forms of the same update: `scalar_update_6` for a row that observes one component of a 6-state filter
(mekf: h = sign·e_j), written out for the compiler; `pair_update_6` for a row that observes a combination of
two (mekf's levelling across a lean: h = a·e_i + b·e_j); `scalar_update` for any row of an n-state filter (ins).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def scalar_update_6(P, j, sign, nu, r, zero_mask):
    """The constrained update of the 6×6 covariance P for the row h = sign·e_j and innovation nu, variance r.
    Returns the error-state correction K·ν as six scalars."""
    s = P[j, j] + r
    inv_s = 1.0 / s   # one division for the six gains
    u0 = sign * P[0, j]
    u1 = sign * P[1, j]
    u2 = sign * P[2, j]
    u3 = sign * P[3, j]
    u4 = sign * P[4, j]
    u5 = sign * P[5, j]
    k0 = 0.0 if zero_mask & 1 else u0 * inv_s
    k1 = 0.0 if zero_mask & 2 else u1 * inv_s
    k2 = 0.0 if zero_mask & 4 else u2 * inv_s
    k3 = 0.0 if zero_mask & 8 else u3 * inv_s
    k4 = 0.0 if zero_mask & 16 else u4 * inv_s
    k5 = 0.0 if zero_mask & 32 else u5 * inv_s
    # the 21 entries of the upper triangle, mirrored (the update is symmetric by construction), written out:
    # numba keeps the gains in registers this way, not in a tuple indexed in a loop
    P[0, 0] += s * k0 * k0 - 2.0 * k0 * u0
    P[0, 1] = P[1, 0] = P[0, 1] - k0 * u1 - u0 * k1 + s * k0 * k1
    P[0, 2] = P[2, 0] = P[0, 2] - k0 * u2 - u0 * k2 + s * k0 * k2
    P[0, 3] = P[3, 0] = P[0, 3] - k0 * u3 - u0 * k3 + s * k0 * k3
    P[0, 4] = P[4, 0] = P[0, 4] - k0 * u4 - u0 * k4 + s * k0 * k4
    P[0, 5] = P[5, 0] = P[0, 5] - k0 * u5 - u0 * k5 + s * k0 * k5
    P[1, 1] += s * k1 * k1 - 2.0 * k1 * u1
    P[1, 2] = P[2, 1] = P[1, 2] - k1 * u2 - u1 * k2 + s * k1 * k2
    P[1, 3] = P[3, 1] = P[1, 3] - k1 * u3 - u1 * k3 + s * k1 * k3
    P[1, 4] = P[4, 1] = P[1, 4] - k1 * u4 - u1 * k4 + s * k1 * k4
    P[1, 5] = P[5, 1] = P[1, 5] - k1 * u5 - u1 * k5 + s * k1 * k5
    P[2, 2] += s * k2 * k2 - 2.0 * k2 * u2
    P[2, 3] = P[3, 2] = P[2, 3] - k2 * u3 - u2 * k3 + s * k2 * k3
    P[2, 4] = P[4, 2] = P[2, 4] - k2 * u4 - u2 * k4 + s * k2 * k4
    P[2, 5] = P[5, 2] = P[2, 5] - k2 * u5 - u2 * k5 + s * k2 * k5
    P[3, 3] += s * k3 * k3 - 2.0 * k3 * u3
    P[3, 4] = P[4, 3] = P[3, 4] - k3 * u4 - u3 * k4 + s * k3 * k4
    P[3, 5] = P[5, 3] = P[3, 5] - k3 * u5 - u3 * k5 + s * k3 * k5
    P[4, 4] += s * k4 * k4 - 2.0 * k4 * u4
    P[4, 5] = P[5, 4] = P[4, 5] - k4 * u5 - u4 * k5 + s * k4 * k5
    P[5, 5] += s * k5 * k5 - 2.0 * k5 * u5
    return k0 * nu, k1 * nu, k2 * nu, k3 * nu, k4 * nu, k5 * nu


@njit(cache=True)
def pair_update_6(P, i, a, j, b, nu, r, zero_mask):
    """The constrained update of the 6×6 covariance P for the row h = a·e_i + b·e_j (i ≠ j) and innovation nu,
    variance r. Returns the error-state correction K·ν as six scalars. (u and K as tuples, as in
    `scalar_update_6`: a step allocates nothing.)"""
    u = (a * P[0, i] + b * P[0, j], a * P[1, i] + b * P[1, j], a * P[2, i] + b * P[2, j],
         a * P[3, i] + b * P[3, j], a * P[4, i] + b * P[4, j], a * P[5, i] + b * P[5, j])
    s = a * u[i] + b * u[j] + r
    inv_s = 1.0 / s
    k = (0.0 if zero_mask & 1 else u[0] * inv_s, 0.0 if zero_mask & 2 else u[1] * inv_s,
         0.0 if zero_mask & 4 else u[2] * inv_s, 0.0 if zero_mask & 8 else u[3] * inv_s,
         0.0 if zero_mask & 16 else u[4] * inv_s, 0.0 if zero_mask & 32 else u[5] * inv_s)
    for m in range(6):
        for n in range(m, 6):
            P[m, n] += -k[m] * u[n] - u[m] * k[n] + s * k[m] * k[n]
            P[n, m] = P[m, n]
    return k[0] * nu, k[1] * nu, k[2] * nu, k[3] * nu, k[4] * nu, k[5] * nu


@njit(cache=True)
def scalar_update(P, h, nu, r, zero_mask, dx):
    """The constrained update of the n×n covariance P for the row h (n,) and innovation `nu` (already
    reduced by h·dx of the earlier updates of the same epoch: `residual`), variance r. Accumulates K·ν into
    dx (n,)."""
    n = h.shape[0]
    u = np.zeros(n)
    for j in range(n):
        hj = h[j]
        if hj != 0.0:
            for i in range(n):
                u[i] += P[i, j] * hj
    s = r
    for j in range(n):
        s += h[j] * u[j]
    k = np.zeros(n)
    for i in range(n):
        if not (zero_mask >> i) & 1:
            k[i] = u[i] / s
    for i in range(n):
        for j in range(n):
            P[i, j] += -k[i] * u[j] - u[i] * k[j] + s * k[i] * k[j]
    for i in range(n):
        dx[i] += k[i] * nu


@njit(cache=True)
def residual(h, nu, dx):
    """Innovation left after the corrections dx already found in this epoch: ν − h·dx."""
    for j in range(h.shape[0]):
        nu -= h[j] * dx[j]
    return nu
