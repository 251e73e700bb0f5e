"""A filter's start, taken by shorter ways (the fixed cost of every `Mekf()` + `run_batch`), gives what the long
ways gave: the initial attitude's Davenport quaternion without the solver's checks, loss and covariance; the state
zeroed as one fill of its bytes; the parameters' record built once per parameter set; the batch's rows of samples
that could not initialise NaN without a NaN-filled array behind them."""

from __future__ import annotations

import math

import numpy as np

from ahrsd.core.sample import ImuSample
from ahrsd.estimator import mekf_core as core
from ahrsd.estimator import wahba
from ahrsd.estimator.mekf import DEFAULT_MEKF_PARAMS, FIXED_WING_MEKF_PARAMS, Mekf


def test_davenport_q_is_davenports_quaternion_bit_for_bit():
    rng = np.random.default_rng(3)
    for _ in range(500):
        body = rng.normal(size=(2, 3)) * rng.uniform(0.1, 50.0, size=(2, 1))   # not unit: normalised alike
        ref = rng.normal(size=(2, 3)) * rng.uniform(0.1, 50.0, size=(2, 1))
        w = rng.uniform(1.0, 1e4, size=2)
        np.testing.assert_array_equal(wahba.davenport_q(body, ref, w), wahba.davenport(body, ref, w).q_wxyz)


def _samples(n, rate_hz=100.0):
    rng = np.random.default_rng(1)
    t = np.arange(n) / rate_hz
    g = rng.normal(0.0, 0.01, (n, 3))
    a = np.array([0.5, -0.3, -9.78]) + rng.normal(0.0, 0.05, (n, 3))
    m = np.array([18.0, 2.0, 42.0]) + rng.normal(0.0, 0.3, (n, 3))
    return t, g, a, m


def test_reset_zeroes_every_byte_of_the_state_and_nothing_else():
    t, g, a, m = _samples(300)
    est = Mekf()
    est.run_batch(t, g, a, m)
    par = est._buf[0]["par"].tobytes()
    out = est._buf[0]["out"].tobytes()
    assert any(est._buf[0]["state"].tobytes())
    est.reset()
    assert est._buf[0]["state"].tobytes() == np.zeros(1, core.MEKF_STATE_DTYPE).tobytes()
    assert est._buf[0]["par"].tobytes() == par and est._buf[0]["out"].tobytes() == out


def test_each_filter_runs_on_the_record_of_its_own_parameters():
    for params in (DEFAULT_MEKF_PARAMS, FIXED_WING_MEKF_PARAMS, DEFAULT_MEKF_PARAMS, None):
        est = Mekf(params=params) if params is not None else Mekf(turn_speed_m_s=7.0)
        assert est._buf[0]["par"].tobytes() == est.params.to_record().tobytes()
    assert Mekf(turn_speed_m_s=7.0)._buf[0]["par"]["turn_speed_m_s"] == 7.0


def test_the_batchs_rows_before_the_filter_could_start_are_nan_as_updates_say():
    t, g, a, m = _samples(200)
    a[:5] = 0.0                     # no gravity: no initialisation
    t[120:] += 5.0                  # a gap: re-initialised, and that sample too has no gravity
    a[120:123] = 0.0
    q, fl = Mekf().run_batch(t, g, a, m)
    one = Mekf()
    for i in range(len(t)):
        est = one.update(ImuSample(t[i], g[i], a[i], m[i]))
        if math.isnan(est.roll_rad):   # (update flags these INITIALISING, the batch 0: as before)
            assert np.all(np.isnan(q[i])), i
        else:
            np.testing.assert_array_equal(q[i], est.q_wxyz)
            assert fl[i] == int(est.flags), i
    assert np.isnan(q[:5]).all() and np.isnan(q[120:123]).all() and not np.isnan(q[5:120]).any()
