"""constrained_update.pair_update_6 (mekf's levelling across a lean: a row on two error-state components) is the
constrained Joseph-form update of the general n-state `scalar_update` (ins's, written independently with loops
and arrays) for the same row, innovation, variance and zero mask."""

from __future__ import annotations

import numpy as np
import pytest

from ahrsd.estimator.constrained_update import pair_update_6, scalar_update


@pytest.mark.parametrize("i, a, j, b, mask", [(0, -0.6, 1, 0.8, 0b000100), (1, 1.0, 0, -0.3, 0b111100),
                                              (2, 0.5, 4, 2.0, 0b000011)])
def test_pair_update_is_the_general_update_for_the_same_row(i, a, j, b, mask):
    rng = np.random.default_rng(7)
    m = rng.normal(size=(6, 6))
    p_pair = m @ m.T + np.eye(6)
    p_general = p_pair.copy()
    h = np.zeros(6)
    h[i], h[j] = a, b
    dx = np.zeros(6)
    d = pair_update_6(p_pair, i, a, j, b, 0.3, 0.5, mask)
    scalar_update(p_general, h, 0.3, 0.5, mask, dx)
    assert np.allclose(p_pair, p_general, rtol=0.0, atol=1e-12)
    assert np.allclose(np.array(d), dx, rtol=0.0, atol=1e-14)
    assert np.all(np.array(d)[[k for k in range(6) if mask >> k & 1]] == 0.0)   # the masked gains are zero
    assert np.array_equal(p_pair, p_pair.T)
