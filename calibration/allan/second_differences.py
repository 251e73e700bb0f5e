"""The overlapping Allan variance's sum of squared second differences over one chunk, compiled (numba): the
streaming estimator (adev._Level.add) runs it for some dozen cluster sizes over every chunk of a record of
millions of samples, where numpy would build three temporaries of the chunk's size per cluster size.

It does element by element what the numpy expressions in its docstring do, in the same order (numpy's einsum
over the rows of a C-ordered (n, k) array, k ≥ 2, accumulates each column row by row; a single column it sums in
blocks, so adev keeps numpy for one column), so the sums do not depend on which one ran.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def add_squared_second_differences(theta: np.ndarray, sizes: np.ndarray, old: int, sum_sq: np.ndarray,
                                   count: np.ndarray) -> None:
    """For each cluster size m = sizes[i], the windows theta[s : s + 2m + 1] that end in the new values
    (s + 2m − 1 ≥ old, s ≤ len(theta) − 1 − 2m):
        d = theta[s + 2m] − 2.0·theta[s + m] + theta[s];  sum_sq[i] += einsum("ij,ij->j", d, d);
        count[i] += the number of windows.
    theta (n + 1, k): the running sums of the buffered values (old of them buffered before this chunk)."""
    n_values = theta.shape[0] - 1
    n_axes = theta.shape[1]
    acc = np.zeros(n_axes)
    for i in range(sizes.shape[0]):
        m = sizes[i]
        first = max(0, old - 2 * m + 1)
        last = n_values - 2 * m           # inclusive
        if last < first:
            continue
        acc[:] = 0.0
        for s in range(first, last + 1):   # row by row, each column's sum in its own accumulator, as einsum's
            for j in range(n_axes):
                d = (theta[s + 2 * m, j] - 2.0 * theta[s + m, j]) + theta[s, j]
                acc[j] += d * d
        for j in range(n_axes):
            sum_sq[i, j] += acc[j]
        count[i] += last - first + 1
