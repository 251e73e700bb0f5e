"""The drift of the gyro bias mekf learnt from motion, while no levelling corrects it
(turn_lean.track_lean_bias_drift): worked numbers, and the case that showed it — the simulator's coordinated turn
(seed 2): the rest detector still declares rest for 0.5 s of the roll-in's start and learns 0.04 °/s of body-x
"bias" (truth), then the bank rejects every levelling update and that bias turns the estimate by ≈ 0.5° beside
the ≈ 0.8° of lean the levelling took in the roll-in.
Truth is the simulator's attitude; the error rotation is computed with scipy, not the estimator's rotations."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.estimator.turn_lean import TURN_LEAN_DTYPE, RestLearning, track_lean_bias_drift

_IDENTITY = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
_ZERO = (0.0, 0.0, 0.0)
_NOT_AT_REST = RestLearning(False, 1.0, _ZERO)


def _record():
    return np.zeros(1, dtype=TURN_LEAN_DTYPE).view(np.recarray)[0]


def test_the_learnt_bias_drifts_into_the_sum_only_while_no_levelling_is_accepted():
    u = _record()
    b = math.radians(0.05)   # rad/s about body x, learnt in one summed step
    track_lean_bias_drift(u, 0.01, _IDENTITY, True, True, (b, 0.0, 0.0), _NOT_AT_REST)
    assert u.lean_drift_n_rad == 0.0 and u.lean_drift_e_rad == 0.0   # levelled: its corrections are summed
    for _ in range(1000):                                                # 10 s rejected, body = NED
        track_lean_bias_drift(u, 0.01, _IDENTITY, False, False, _ZERO, _NOT_AT_REST)
    # the estimate turns by −b·t about north: −0.5°
    assert u.lean_drift_n_rad == pytest.approx(-math.radians(0.5), rel=1e-9)
    assert u.lean_drift_e_rad == 0.0
    # body x pointing east (yawed 90°: C_b^n row 1 = (1, 0, 0)): the drift goes to the east axis
    v = _record()
    track_lean_bias_drift(v, 0.0, _IDENTITY, True, True, (b, 0.0, 0.0), _NOT_AT_REST)
    yawed = (0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0)
    track_lean_bias_drift(v, 2.0, yawed, False, False, _ZERO, _NOT_AT_REST)
    assert v.lean_drift_n_rad == 0.0
    assert v.lean_drift_e_rad == pytest.approx(-2.0 * b, rel=1e-12)


def test_what_rest_learnt_over_the_detectors_lag_counts_as_learnt_from_motion_when_the_rest_ends():
    u = _record()
    keep = math.exp(-0.01 / 0.5)
    for _ in range(100):   # 1 s at rest learning 1e-5 rad/s per step about body y
        track_lean_bias_drift(u, 0.01, _IDENTITY, False, True, _ZERO, RestLearning(True, keep, (0.0, 1e-5, 0.0)))
    assert u.lean_drift_n_rad == 0.0 and u.lean_drift_e_rad == 0.0 and u.lean_bias_rad_s[1] == 0.0
    recent = 1e-5 * (1.0 - keep**100) / (1.0 - keep)   # the geometric sum of the forgotten steps
    track_lean_bias_drift(u, 0.01, _IDENTITY, False, False, _ZERO, RestLearning(False, keep, _ZERO))
    assert u.lean_bias_rad_s[1] == pytest.approx(recent, rel=1e-12)
    assert u.lean_drift_e_rad == pytest.approx(-recent * 0.01, rel=1e-12)   # body y = east: turns about east
    track_lean_bias_drift(u, 0.01, _IDENTITY, False, False, _ZERO, RestLearning(False, keep, _ZERO))
    assert u.lean_bias_rad_s[1] == pytest.approx(recent, rel=1e-12)          # transferred once


@pytest.mark.slow
def test_the_coordinated_turns_bank_keeps_pitch_within_3_sigma():
    """bench/mekf_sigma.py coordinated-turn seed 2, 20.0–21.5 s: the pitch error (≈ 1.1°) within 3σ."""
    from ahrsd.core.sample import ImuSample
    from ahrsd.estimator.mekf import Mekf
    from bench.accuracy import simulate_through_driver

    d, truth, decl = simulate_through_driver("coordinated-turn", 21.5, 2)
    f = Mekf()
    t = d.t_s - d.t_s[0]
    window = t >= 20.0
    q = np.full((len(t), 4), np.nan)
    sig = np.full((len(t), 3), np.nan)
    for i in range(len(t)):
        v = f.step(ImuSample(d.t_s[i], d.gyro_rad_s[i], d.accel_m_s2[i], d.mag_ut[i], int(d.flags[i])))
        if window[i] and v.valid:
            s = v.snapshot()
            q[i] = s.q_wxyz
            sig[i] = s.sigma_rpy_rad
    q, sig, qt = q[window], sig[window], truth[window]
    assert np.all(np.isfinite(q))
    r_true = Rotation.from_quat(qt[:, [1, 2, 3, 0]])
    e = (Rotation.from_rotvec([0.0, 0.0, decl]) * Rotation.from_quat(q[:, [1, 2, 3, 0]]) * r_true.inv()).as_rotvec()
    c = r_true.as_matrix()
    yaw = np.arctan2(c[:, 1, 0], c[:, 0, 0])
    pitch_err = -np.sin(yaw) * e[:, 0] + np.cos(yaw) * e[:, 1]
    assert np.max(np.abs(pitch_err)) > math.radians(0.8)          # the case: a large error the gyro left
    assert np.mean(np.abs(pitch_err) > 3.0 * sig[:, 1]) <= 0.01
