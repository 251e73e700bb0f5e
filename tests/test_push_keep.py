"""mekf_core._push_keep: the speed change's sum's forgetting exp(−Δt/ACCEL_PUSH_MEMORY_S), cached per Δt, must be
the number computed afresh at every step, whatever the sequence of steps (a repeated Δt, a changed one, a zero
step on an unset record), compared bit for bit against math.exp."""

import math

import numpy as np
from numba import njit

from ahrsd.estimator.mekf_core import LOWPASS_WEIGHT_DTYPE, _push_keep
from ahrsd.estimator.turn_lean import ACCEL_PUSH_MEMORY_S


@njit
def _keeps(w, dts):
    out = np.empty(dts.shape[0])
    for i in range(dts.shape[0]):
        out[i] = _push_keep(w[0], dts[i])
    return out


def test_push_keep_is_the_fresh_exp_for_every_step():
    # a zero step first (the unset record holds Δt = 0 with k = 0, not exp(0) = 1), then repeats and changes
    dts = np.array([0.0, 0.0, 1 / 819.2, 1 / 819.2, 1 / 204.8, 1 / 819.2, 0.0, 0.5, 0.5, 1 / 819.2])
    w = np.zeros(1, LOWPASS_WEIGHT_DTYPE)
    got = _keeps(w, dts)
    want = np.array([math.exp(-dt / ACCEL_PUSH_MEMORY_S) for dt in dts])
    assert np.array_equal(got, want), (got, want)
