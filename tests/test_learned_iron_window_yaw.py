"""A learned iron keeps its learning window's yaw error, and its prior says so (issue 28, iron30).

The iron is learned against the filter's attitude. A yaw error common to the whole learning window (the filter's
yaw a couple of degrees off for a minute, as on the uncalibrated boat's seed 31) turns the Earth field about the
vertical in every measurement, and an iron free to rotate the field (the uncalibrated magnetometer's soft-iron
prior) learns it: the learned magnetometer then reads every heading off by that yaw error. The learner counted the
attitude's uncertainty as noise refreshed every `iron_tau_s`, so its covariance averaged that error down; the
harmonic states' prior (`MagErrorStates.iron_prior`, estimator/mag_error_states.py) must carry it (estimator/learned_iron.py).

Truth is independent of the code under test: the magnetometer is a known iron applied to the simulator's WMM field
at the true (level) attitude, and the learned magnetometer's heading error is the azimuth of the field it
corrects against the field's true azimuth (straight trigonometry)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ahrsd.estimator import ins_core as core
from ahrsd.estimator.ins import Ins
from ahrsd.simulation import DEFAULT_SITE

FIELD_NED_UT = np.asarray(DEFAULT_SITE.earth_field().ned_ut, dtype=float)
HARD_IRON_UT = np.array([6.0, -4.0, 3.0])
SOFT_IRON = np.array([[1.04, 0.02, 0.0], [-0.01, 0.97, 0.01], [0.0, 0.02, 1.0]])
WINDOW_YAW_ERROR_DEG = 2.0      # the filter's yaw over the whole learning window, off by its stated 1σ
WINDOW_YAW_SIGMA_DEG = 2.0
CHECK_S = 0.2                   # the heading checks' rate (the GNSS fixes'), as Ins._learn_iron is called
HEADINGS_RAD = np.linspace(0.0, 2.0 * math.pi, 16, endpoint=False)


def _level(yaw_rad: float) -> np.ndarray:
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _measured(yaw_rad: float, soft=SOFT_IRON, hard=HARD_IRON_UT) -> np.ndarray:
    return soft @ (_level(yaw_rad).T @ FIELD_NED_UT) + hard


def _learn(est: Ins, turn_rad: float, yaw_error_deg: float, seconds: float = 120.0, iron=(SOFT_IRON, HARD_IRON_UT)
           ) -> None:
    """The learning window: a level vehicle turning through `turn_rad` at a constant rate, the filter's yaw off by
    `yaw_error_deg` throughout and stating WINDOW_YAW_SIGMA_DEG (tilt 0.1°), each check one learning step; the
    magnetometer `iron` (soft, hard) on the field."""
    att = slice(core.E_TH, core.E_TH + 3)
    est._P[att, att] = np.diag(np.radians([0.1, 0.1, WINDOW_YAW_SIGMA_DEG]) ** 2)
    est._par["mag_use"] = 0.0     # not fused while its iron is learned (magnetometer_use.py), as in a run
    rng = np.random.default_rng(7)
    n = int(seconds / CHECK_S)
    for i in range(n):
        yaw = turn_rad * i / n
        est._x["mag_last_ut"] = _measured(yaw, *iron) + rng.normal(0.0, 0.1, 3)
        est._heading._learn_iron(i * CHECK_S, _level(yaw + math.radians(yaw_error_deg)), FIELD_NED_UT)
    est._heading.field_ned = FIELD_NED_UT


def _learned_heading_errors_deg(est: Ins, iron=(SOFT_IRON, HARD_IRON_UT)) -> np.ndarray:
    """The learned magnetometer's heading error (read − true) of a level vehicle at HEADINGS_RAD."""
    ref = math.atan2(FIELD_NED_UT[1], FIELD_NED_UT[0])
    out = []
    for psi in HEADINGS_RAD:
        c = _level(psi)
        horizontal = c @ est._iron.corrected(_measured(psi, *iron))
        out.append(-math.remainder(math.atan2(horizontal[1], horizontal[0]) - ref, 2.0 * math.pi))
    return np.degrees(out)


def _offset_sigma_deg(est: Ins) -> float:
    """The harmonic states' prior for the learned iron: its constant term's 1σ (c0, the heading offset)."""
    return math.degrees(math.sqrt(est._mag_errors.iron_prior(est.params, est._heading.field_ned, est._declination)[0, 0]))


@pytest.mark.parametrize("turn_rad", [2.0 * math.pi, math.pi])
def test_an_uncalibrated_iron_learns_the_window_yaw_error_and_its_prior_covers_it(turn_rad):
    est = Ins()      # no calibration: the soft iron's prior (0.1) lets the learned iron turn the field
    _learn(est, turn_rad, WINDOW_YAW_ERROR_DEG)
    errors = _learned_heading_errors_deg(est)
    offset = float(np.mean(errors))
    # the premise: the learned magnetometer reads every heading off by the window's yaw error
    assert abs(offset - WINDOW_YAW_ERROR_DEG) < 0.2, errors
    # the learner's own covariance averaged it down (what the prior was: well inside 3σ would not be honest)
    from ahrsd.estimator.mag_harmonics import prior_from_heading_rows
    yaw = np.linspace(0.0, 2.0 * math.pi, 16, endpoint=False)
    own = prior_from_heading_rows(est._iron.level_heading_rows(FIELD_NED_UT, yaw), yaw - est._declination,
                                  est._iron.cov)
    assert abs(offset) > 2.0 * math.degrees(math.sqrt(own[0, 0]))
    # the prior the filter uses covers it: about the window's yaw σ, as the error was 1σ of it
    sigma = _offset_sigma_deg(est)
    assert abs(offset) <= 1.2 * sigma
    assert sigma < 1.5 * WINDOW_YAW_SIGMA_DEG


def test_a_right_window_yaw_learns_a_right_iron_with_the_same_prior():
    # the share is the window's yaw uncertainty, not its error: a right yaw gives the same prior, the error ~0
    est = Ins()
    _learn(est, 2.0 * math.pi, 0.0)
    assert abs(float(np.mean(_learned_heading_errors_deg(est)))) < 0.1
    assert _offset_sigma_deg(est) > 0.8 * WINDOW_YAW_SIGMA_DEG


def test_a_calibrated_magnetometer_pins_the_rotation_and_its_prior_widens_only_by_what_the_iron_took():
    # a calibration stating 0.5° leaves the soft iron's prior at 0.5° (InsParams.iron_soft_prior): a relearned
    # iron (the iron-step case: the calibrated field plus a 9 µT step of the hard iron) cannot turn the field by the
    # window's 2°, so the offset it takes and the prior's widening are a fraction of it, and the prior covers it
    step = (np.eye(3), np.array([6.0, -5.0, 4.5]))
    est = Ins(mag_calibration_sigma_rad=math.radians(0.5))
    _learn(est, 2.0 * math.pi, WINDOW_YAW_ERROR_DEG, iron=step)
    offset = float(np.mean(_learned_heading_errors_deg(est, step)))
    sigma = _offset_sigma_deg(est)
    assert abs(offset) < 0.4 * WINDOW_YAW_ERROR_DEG
    assert abs(offset) <= 1.5 * sigma
    assert sigma < 0.5 * WINDOW_YAW_SIGMA_DEG


def test_a_reset_or_restored_iron_forgets_the_window():
    # the floor fused as noise (session 41 carries it in the prior: its c0 share, 1.03° here, would mask the window's)
    est = Ins(iron_harmonic_residual_share=1.0)
    _learn(est, 2.0 * math.pi, WINDOW_YAW_ERROR_DEG)
    offset_ut, cov = est.learned_iron()
    soft, soft_cov = est.learned_soft_iron()
    est.set_learned_iron(offset_ut, cov, soft, soft_cov)     # the daemon's restored iron (without its cross terms)
    est._heading.field_ned = FIELD_NED_UT
    restored = _offset_sigma_deg(est)
    assert restored < 0.5 * WINDOW_YAW_SIGMA_DEG     # a restored iron's window is not persisted: its own σ only
    est.reset_learned_iron()
    assert not np.any(est._learned_iron.yaw_share.share)
