"""bench/heading_split.py's rows "offset as a state" and "offset as a state, with the yaw" (docs/gnss.md "(iron37)"):
where the magnetometer is fused while its iron is learned and the learned offset is held, the offset's error is
carried as the harmonic state c0 alone; with the yaw, c0 starts as own + Γ·δθ_D, and Γ must be how much of a yaw
error common to the learning window the learned offset took in, with the kernel's sign (its heading row is
−δθ_D + c0).

Truth is independent of the code under test: the magnetometer is a known iron applied to the WMM field at the true
(level) attitude; the learned magnetometer's heading error is the azimuth of the field it corrects against the
field's true azimuth (straight trigonometry), and the filter's yaw is off by a known constant over the window."""

from __future__ import annotations

import math

import numpy as np

from ahrsd.estimator import ins_core as core
from ahrsd.estimator.ins import Ins
from support.level_iron_turn import CHECK_S, FIELD_NED_UT, HEADINGS_RAD
from support.level_iron_turn import level as _level
from support.level_iron_turn import measured as _measured
from bench.heading_split import offset_as_state

# the field and the iron (support/level_iron_turn.py): Anchorage, H about 15 µT, where the learned magnetometer is
# never trusted (fused while it is learned)
YAW_ERROR_DEG = 2.0         # the filter's yaw (estimate − truth) over the whole window, at its stated 1σ


def _learned(with_yaw: bool) -> Ins:
    """A 90 s learning window over a full turn, the filter's yaw YAW_ERROR_DEG off throughout (not fused, so nothing
    is held while learning: the offset takes the error in), then the offset held and the checks' conditions for the
    rows met (the magnetometer fused while learning, the filter aided); the harmonics selected as a check does."""
    est = Ins()
    offset_as_state(est, with_yaw)
    att = slice(core.E_TH, core.E_TH + 3)
    est._P[att, att] = np.diag(np.radians([0.1, 0.1, YAW_ERROR_DEG]) ** 2)
    est._par["mag_use"] = 0.0
    rng = np.random.default_rng(3)
    n = int(90.0 / CHECK_S)
    for i in range(n):
        yaw = 2.0 * math.pi * i / n
        est._x["mag_last_ut"] = _measured(yaw) + rng.normal(0.0, 0.1, 3)
        est._heading._learn_iron(i * CHECK_S, _level(yaw + math.radians(YAW_ERROR_DEG)), FIELD_NED_UT)
    est._iron.offset_held = True
    est._par["mag_use"] = 1.0
    est._heading.monitor.learning = True
    est._heading.ever_aided = True
    est._heading.field_ned = FIELD_NED_UT
    est._heading.set_mag_harmonics()
    return est


def _learned_azimuth_error_rad(est: Ins) -> float:
    """The learned magnetometer's field azimuth error (read − true) averaged over a level turn: its c0."""
    ref = math.atan2(FIELD_NED_UT[1], FIELD_NED_UT[0])
    out = [math.remainder(math.atan2(*(_level(psi) @ est._iron.corrected(_measured(psi)))[1::-1]) - ref, 2 * math.pi)
           for psi in HEADINGS_RAD]
    return float(np.mean(out))


def test_the_offset_alone_is_carried_uncorrelated():
    est = _learned(with_yaw=False)
    assert est._mag_errors.source == "offset" and est._par["mag_harmonics_on"] > 0.0
    block = est._P[core.E_MH:core.E_MH + 5, core.E_MH:core.E_MH + 5]
    assert block[0, 0] > 0.0 and not np.any(block[1:, :]) and not np.any(block[:, 1:])
    assert est._P[core.E_MH, core.E_YAW] == 0.0


def test_with_the_yaw_c0_follows_the_yaw_error_the_window_left_in_it():
    est = _learned(with_yaw=True)
    P = est._P
    gamma = P[core.E_MH, core.E_YAW] / P[core.E_YAW, core.E_YAW]
    # the kernel's yaw error state is truth − estimate: the window's yaw error, −YAW_ERROR_DEG
    d_theta_d = -math.radians(YAW_ERROR_DEG)
    learned = _learned_azimuth_error_rad(est)
    assert abs(learned) > math.radians(1.5)       # the premise: the offset took most of the error in
    assert math.degrees(abs(gamma * d_theta_d - learned)) < 0.2, (gamma, math.degrees(learned))
    assert P[core.E_MH, core.E_MH] >= gamma * gamma * P[core.E_YAW, core.E_YAW]
