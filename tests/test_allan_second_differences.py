"""The compiled sum of squared second differences (calibration/allan/second_differences.py), which the streaming
Allan deviation runs for records of several columns: the definition written out with loops, and each column
read alone (one column takes adev's numpy expressions, not the kernel), whatever the chunks."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ahrsd.calibration.allan.adev import StreamingAllan, allan_deviation


def test_several_columns_match_the_definition():
    """σ²(τ) = 1/(2τ²(N−2m+1)) Σ (θ_{k+2m} − 2θ_{k+m} + θ_k)² per column, written out with loops."""
    rng = np.random.default_rng(8)
    rate = 10.0
    sizes = [1, 2, 5, 13, 40]
    for cols in (2, 3):
        x = rng.normal(size=(300, cols)) + np.linspace(0, 1, 300)[:, None] * np.arange(1, cols + 1)
        curve = allan_deviation(x, rate, m=np.array(sizes))
        for c in range(cols):
            theta = np.concatenate([[0.0], np.cumsum(x[:, c])]) / rate
            for tau, value, nt, m in zip(curve.taus_s, curve.adev[:, c], curve.n_terms, sizes):
                terms = [(theta[k + 2 * m] - 2 * theta[k + m] + theta[k]) ** 2 for k in range(len(x) + 1 - 2 * m)]
                assert nt == len(terms)
                assert value == pytest.approx(math.sqrt(sum(terms) / (2 * tau * tau * len(terms))), rel=1e-10)


@pytest.mark.parametrize("decimate", [False, True])
def test_chunks_shorter_than_a_window_count_every_window_once(decimate):
    """Fed in chunks shorter than the windows (each window then spans several chunks), every column's curve is
    the curve of that column alone, fed whole."""
    rng = np.random.default_rng(9)
    x = rng.normal(size=(6000, 3)) + 2.0
    kw = {"level0_sizes": (1, 3, 7, 20, 50), "decimate": False} if not decimate else {}
    acc = StreamingAllan(20.0, 3, **kw)
    start = 0
    for size in [1, 2, 3, 5, 17, 1, 64, 9] * 60:
        acc.add(x[start:start + size])
        start += size
    acc.add(x[start:])
    parts = acc.curve(max_tau_fraction=0.5) if not decimate else acc.curve()
    for c in range(3):
        alone = StreamingAllan(20.0, 1, **kw)
        alone.add(x[:, c])
        whole = alone.curve(max_tau_fraction=0.5) if not decimate else alone.curve()
        np.testing.assert_array_equal(parts.taus_s, whole.taus_s)
        np.testing.assert_array_equal(parts.n_terms, whole.n_terms)
        np.testing.assert_allclose(parts.adev[:, c], whole.adev[:, 0], rtol=1e-11)
