"""What mekf's rest learning taught the gyro bias over the rest detector's lag (turn_lean.track_lean_bias_drift,
`rest_bias_recent_rad_s`): at every step at rest it is the at-rest changes of the bias estimate forgotten by
exp(−Δt/rest_filter_tau_s) per step, and the step the rest ends it moves into the bias learnt from motion
(`lean_bias_rad_s`), once. Without a rest it stays zero.

The input is constructed so the at-rest change of the bias estimate is the whole change: level and still with a
gyro bias about the vertical only, the magnetometer off. Rotating about the vertical leaves the levelled vertical
exactly vertical, so no levelling update moves the bias and the only learning is the rest's. The expected values
are computed here from the bias estimates the filter publishes (the view's `gyro_bias_rad_s`) and the documented
forgetting, not by the code under test; the step path and the batch path are both checked."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ahrsd.core.sample import ImuSample
from ahrsd.estimator import mekf_core as core
from ahrsd.estimator.mekf import Mekf

_DT_S = 1.0 / 200.0
_BIAS_Z_RAD_S = math.radians(0.3)
_STILL_S = 6.0                   # at rest from rest_min_time_s (1.5 s) on, the bias learnt in its first second
_RAMP_RAD_S2 = math.radians(4.0)  # then a slow spin-up about the vertical: the detector sees it late
_ACC_M_S2 = np.array([0.0, 0.0, -9.80665])
_MAG_UT = np.array([20.0, 0.0, 40.0])


def _input(n):
    t = np.arange(n) * _DT_S
    gyro = np.zeros((n, 3))
    gyro[:, 2] = _BIAS_Z_RAD_S + _RAMP_RAD_S2 * np.maximum(t - _STILL_S, 0.0)
    return t, gyro


def _stepped(rest_min_time_s=None):
    """Step the filter through the input; per step: at rest, the bias estimate, the two tracked records."""
    f = Mekf(mag_enabled=False) if rest_min_time_s is None else Mekf(mag_enabled=False,
                                                                     rest_min_time_s=rest_min_time_s)
    t, gyro = _input(int(9.0 / _DT_S))
    rows = []
    for i in range(len(t)):
        v = f.step(ImuSample(t[i], gyro[i], _ACC_M_S2, _MAG_UT))
        u = f._state["unmodelled"]
        rows.append((v.valid and bool(v.flags & core.F_AT_REST), v.gyro_bias_rad_s[2] if v.valid else 0.0,
                     u["rest_bias_recent_rad_s"][2], u["lean_bias_rad_s"][2]))
    return f, rows


def _expected_recent(rows, keep):
    """rest_bias_recent by the documented rule: r ← r·keep + δb̂ at each step at rest."""
    r = 0.0
    out = []
    for i, (at_rest, b, _, _) in enumerate(rows):
        if at_rest and i > 0:
            r = r * keep + (b - rows[i - 1][1])
        out.append(r)
    return out


def test_what_rest_learnt_is_forgotten_over_its_filter_time_and_moves_to_the_motion_bias_when_rest_ends():
    f, rows = _stepped()
    keep = math.exp(-_DT_S / f.params.rest_filter_tau_s)
    rest = [r[0] for r in rows]
    first = rest.index(True)
    end = first + rest[first:].index(False)           # the first step out of rest
    assert end * _DT_S > _STILL_S + 0.1                # the detector's lag: rest still declared in the spin-up
    assert not any(rest[end:])
    want = _expected_recent(rows, keep)
    got = [r[2] for r in rows]
    for i in range(first, end):
        assert got[i] == pytest.approx(want[i], rel=1e-9, abs=1e-15), i
    # the learnt bias's first second is forgotten (keep ≈ 0.99 per step): what is left is the spin-up's start
    # (of the order of the ramp's rate over the lag), not the whole 0.3 °/s learnt
    recent = want[end - 1]
    assert 0.0 < recent < 0.2 * _BIAS_Z_RAD_S
    assert recent > 10.0 * want[int(_STILL_S / _DT_S) - 1]    # learnt in the lag, not left from the start
    # the rest ends: what it learnt recently becomes bias learnt from motion, once
    assert got[end] == 0.0
    assert rows[end][3] == pytest.approx(recent, rel=1e-9)
    assert all(r[3] <= rows[end][3] * (1.0 + 1e-12) for r in rows[end:])   # only forgotten after (by the sum's
    assert rows[-1][3] > 0.9 * recent                                      # 30 s memory), not added again


def test_without_rest_nothing_is_learnt_as_rest():
    _, rows = _stepped(rest_min_time_s=100.0)
    assert not any(r[0] for r in rows)
    assert all(r[2] == 0.0 and r[3] == 0.0 for r in rows)


def test_the_batch_leaves_the_steps_state():
    f_step, rows = _stepped()
    rest = [r[0] for r in rows]
    end = rest.index(True) + rest[rest.index(True):].index(False)
    t, gyro = _input(len(rows))
    n = len(t)
    f = Mekf(mag_enabled=False)
    acc = np.tile(_ACC_M_S2, (n, 1))
    mag = np.tile(_MAG_UT, (n, 1))
    f.run_batch(t[:end], gyro[:end], acc[:end], mag[:end])       # up to the last step at rest
    u = f._state["unmodelled"]
    assert u["rest_bias_recent_rad_s"][2] == rows[end - 1][2]
    f.run_batch(t[end:end + 1], gyro[end:end + 1], acc[end:end + 1], mag[end:end + 1])
    assert u["rest_bias_recent_rad_s"][2] == 0.0
    assert u["lean_bias_rad_s"][2] == rows[end][3]
