"""A calibrated magnetometer's error does not average out with time (issue 28: σ must cover the error). What a
calibration leaves is a function of the heading — constant, once and twice per turn (estimator/mag_harmonics.py) —
so while the boat holds a heading it is a bias. ins told the calibration's 1σ must publish a yaw σ that covers it:
|heading error| ≤ 3σ on at least 99 % of the samples after the first 30 s.

The magnetometer here is built from the truth, independently of the estimator: the site's Earth field (the
simulator's WMM) with its azimuth turned by a fixed e(ψ) of the stated size at the true magnetic heading ψ, seen
through the true attitude, plus white noise. The boat's motion, IMU and GNSS fixes are the simulator's
(tests/ins_truth.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from ins_truth import DECLINATION, gnss_fixes, rot, run_ins_with_yaw_sigma, simulated_run, tilt_heading_errors_deg
from scipy.spatial.transform import Rotation

from ahrsd.estimator.ins import Ins
from ahrsd.simulation import DEFAULT_SITE

SECONDS = 180.0
STATED_SIGMA_RAD = math.radians(1.2)     # what the calibration says of itself
# its actual error, rad, at magnetic heading ψ: RMS over ψ 1.20°, what it states; largest (2.0°) on the boat's
# longest legs (magnetic heading 270–290°, 75–105 s and 165–180 s of seed 12)
OFFSET_RAD = math.radians(0.84)
ONCE_RAD, ONCE_PHASE_RAD = math.radians(1.2), math.radians(270.0)
TWICE_RAD = math.radians(0.2)
MAG_NOISE_UT = 0.1
SKIP_S = 30.0


def calibration_error_rad(psi_rad: np.ndarray) -> np.ndarray:
    return OFFSET_RAD + ONCE_RAD * np.cos(psi_rad - ONCE_PHASE_RAD) + TWICE_RAD * np.sin(2.0 * psi_rad)


@pytest.fixture(scope="module")
def boat_with_calibration_error():
    run = simulated_run("boat", SECONDS, rate_hz=200.0, seed=12)
    truth = rot(run.truth.q_wxyz)
    psi_mag = truth.as_euler("ZYX")[:, 0] - DECLINATION
    e = calibration_error_rad(psi_mag)
    field_ned = np.asarray(DEFAULT_SITE.earth_field().ned_ut, dtype=float)
    # the field's azimuth turned by e about down, then into the body frame through the true attitude
    turned = Rotation.from_euler("z", e[:, None]).apply(field_ned)
    rng = np.random.default_rng(5)
    run.mag = truth.inv().apply(turned) + rng.normal(0.0, MAG_NOISE_UT, (len(e), 3))
    return run, gnss_fixes(run.truth)


def _heading_errors_and_sigma_deg(run, fixes, **params):
    ins = Ins(declination_rad=DECLINATION, mag_calibration_sigma_rad=STATED_SIGMA_RAD, **params)
    res, sigma_yaw = run_ins_with_yaw_sigma(ins, run, fixes)
    _, heading = tilt_heading_errors_deg(res.q_mag, run.truth.q_wxyz)
    keep = run.truth.t_s - run.truth.t_s[0] >= SKIP_S
    return heading[keep], np.degrees(np.asarray(sigma_yaw))[keep]


def test_the_boat_holds_headings_long_enough_for_the_error_to_be_a_bias(boat_with_calibration_error):
    """The premise: the error the test builds changes by more than a degree between the boat's legs, and stays
    within the calibration's stated 1σ·√2 at most headings (it is of the stated size)."""
    run, _ = boat_with_calibration_error
    psi = rot(run.truth.q_wxyz).as_euler("ZYX")[:, 0] - DECLINATION
    e_deg = np.degrees(calibration_error_rad(psi))
    assert np.ptp(e_deg) > 1.0
    assert np.sqrt(np.mean(e_deg ** 2)) < math.degrees(STATED_SIGMA_RAD) * math.sqrt(2.0)


def test_published_heading_sigma_covers_a_calibration_error_that_is_a_function_of_heading(
        boat_with_calibration_error):
    run, fixes = boat_with_calibration_error
    err, sigma = _heading_errors_and_sigma_deg(run, fixes)
    within = np.abs(err) <= 3.0 * sigma
    assert np.mean(within) >= 0.99, (
        f"{100 * (1 - np.mean(within)):.1f} % of headings beyond 3σ (RMS {np.sqrt(np.mean(err ** 2)):.2f}°, "
        f"median σ {np.median(sigma):.2f}°)")
    # and not by a σ so wide it says nothing: at most the calibration's own 1σ for most of the run
    assert np.median(sigma) <= math.degrees(STATED_SIGMA_RAD)
