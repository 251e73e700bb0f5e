"""A calibrated magnetometer whose frame is tilted must not make ins's roll and pitch σ over-confident (issue 28:
σ must cover the error).

A vehicle's calibration takes its vertical from a levelling that cannot tell a horizontal accelerometer bias from
a tilt (calibration/mag/levelling_error.py): its frame is tilted as the accelerometer's vertical is, the tilt the
filter's own attitude shares. Through the dip the frame tilt turns the heading once per turn, which the harmonic
states carry (estimator/mag_harmonics.py); the heading row's tilt sensitivity must not read that pattern as the
magnetometer confirming the filter's tilt (docs/estimator.md "roll25": on the user's pipeline the pitch σ shrank in
a full turn while its error stayed). The frame's tilt is two filter states (estimator/mag_frame_tilt.py) with the
calibration's stated levelling tilt for a prior.

The magnetometer is built from the truth, independently of the estimator: the site's Earth field (the simulator's
WMM) seen through the true attitude, then through the frame in which the simulated accelerometer (its turn-on bias
and misalignment, seed 14: 0.68° of pitch) reads level, plus white noise. The calibration states half the heading
error that tilt leaves and half its tilt as its levelling's 1σ per axis (a 2σ calibration). The boat's motion, IMU and GNSS fixes are the simulator's
(tests/ins_truth.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from ins_truth import DECLINATION, gnss_fixes, rot, run_ins, simulated_run
from scipy.spatial.transform import Rotation

from ahrsd.core.angles import STANDARD_GRAVITY_M_S2
from ahrsd.estimator.ins import Ins
from ahrsd.simulation import DEFAULT_SITE, SensorErrors

SECONDS = 300.0     # the boat's full turn at 140–185 s and two minutes after it
SEED = 14           # its accelerometer reads level 0.68° off in pitch: the user's pipeline missed its pitch
MAG_NOISE_UT = 0.1
SKIP_S = 30.0


def accelerometer_levelled_frame_rad(seed: int) -> np.ndarray:
    """The rotation vector (body, rad) of the frame in which the seed's accelerometer reads level when the body
    is: level, it reads f = b − g·(I + M) e_z, whose horizontal part b_h = b − g·M e_z (the bias and what the
    misalignment takes of gravity) leans the measured vertical by (b_y/g, −b_x/g) about x and y."""
    err = SensorErrors.adis16405(seed)
    b = err.accel_bias_m_s2 - STANDARD_GRAVITY_M_S2 * err.accel_misalignment_rad[:, 2]
    return np.array([b[1], -b[0], 0.0]) / STANDARD_GRAVITY_M_S2


def _dip_rad(field_ned: np.ndarray) -> float:
    return math.atan2(field_ned[2], math.hypot(field_ned[0], field_ned[1]))


@pytest.fixture(scope="module")
def boat_with_a_tilted_calibration():
    run = simulated_run("boat", SECONDS, rate_hz=200.0, seed=SEED)
    truth = rot(run.truth.q_wxyz)
    field_ned = np.asarray(DEFAULT_SITE.earth_field().ned_ut, dtype=float)
    tilt = accelerometer_levelled_frame_rad(SEED)
    frame = Rotation.from_rotvec(tilt)
    rng = np.random.default_rng(5)
    run.mag = frame.apply(truth.inv().apply(field_ned)) + rng.normal(0.0, MAG_NOISE_UT, (len(run.truth.t_s), 3))
    # what the calibration states: half the heading error its frame's tilt leaves, tan(dip)·|ε| / 2
    stated = 0.5 * math.tan(_dip_rad(field_ned)) * float(np.linalg.norm(tilt))
    return run, gnss_fixes(run.truth), stated, tilt


def _attitude_errors_and_sigma_deg(run, fixes, stated_sigma_rad, frame_tilt_sigma_rad):
    """(roll, pitch, true heading) errors and published 1σ, deg, per sample after SKIP_S."""
    ins = Ins(declination_rad=DECLINATION, mag_calibration_sigma_rad=stated_sigma_rad,
              mag_calibration_frame_tilt_sigma_rad=frame_tilt_sigma_rad)
    sigma = []
    real_update = ins.update

    def update(sample):
        est = real_update(sample)
        sigma.append(np.asarray(est.sigma_rpy_rad, dtype=float))
        return est

    ins.update = update
    res = run_ins(ins, run, fixes)
    est = (Rotation.from_euler("z", DECLINATION) * rot(res.q_mag)).as_euler("ZYX")
    tru = rot(run.truth.q_wxyz).as_euler("ZYX")
    err = np.degrees((est - tru + math.pi) % (2.0 * math.pi) - math.pi)[:, ::-1]
    keep = run.truth.t_s - run.truth.t_s[0] >= SKIP_S
    return err[keep], np.degrees(np.asarray(sigma))[keep]


def test_the_frame_tilt_turns_the_heading_by_the_stated_amount(boat_with_a_tilted_calibration):
    """The premise: levelled with the true attitude, the tilted frame's field azimuth is off once per turn, by
    more than the tilt itself and about twice the stated 1σ (RMS over the boat's headings)."""
    run, _, stated, tilt = boat_with_a_tilted_calibration
    assert math.degrees(float(np.linalg.norm(tilt))) > 0.5
    field_ned = np.asarray(DEFAULT_SITE.earth_field().ned_ut, dtype=float)
    seen = rot(run.truth.q_wxyz).apply(run.mag)
    off = np.arctan2(seen[:, 1], seen[:, 0]) - math.atan2(field_ned[1], field_ned[0])
    e_deg = np.degrees((off + math.pi) % (2.0 * math.pi) - math.pi)
    assert np.ptp(e_deg) > 2.0 * math.degrees(float(np.linalg.norm(tilt)))
    assert 1.0 * math.degrees(stated) < np.sqrt(np.mean(e_deg ** 2)) < 3.0 * math.degrees(stated)


def test_roll_and_pitch_sigma_cover_their_error_with_a_tilted_calibration(boat_with_a_tilted_calibration):
    """≥ 99 % of roll, pitch and heading within 3σ, and ≥ 90 % of roll and pitch within 2σ: an error that sits
    at 2–3σ for minutes is a σ shrunk by information the magnetometer does not have (without the frame-tilt
    states: pitch 0.7 % beyond 3σ but 45 % beyond 2σ, its σ 0.20 → 0.15° through the turn while the error stayed
    +0.3°)."""
    run, fixes, stated, tilt = boat_with_a_tilted_calibration
    err, sigma = _attitude_errors_and_sigma_deg(run, fixes, stated, 0.5 * float(np.linalg.norm(tilt)))
    beyond3 = [float(np.mean(np.abs(err[:, i]) > 3.0 * sigma[:, i])) for i in range(3)]
    beyond2 = [float(np.mean(np.abs(err[:, i]) > 2.0 * sigma[:, i])) for i in range(3)]
    report = "; ".join(f"{name} {100 * b3:.2f} % beyond 3σ, {100 * b2:.1f} % beyond 2σ (RMS "
                       f"{np.sqrt(np.mean(err[:, i] ** 2)):.2f}°, median σ {np.median(sigma[:, i]):.2f}°)"
                       for i, (name, b3, b2) in enumerate(zip(("roll", "pitch", "heading"), beyond3, beyond2)))
    assert max(beyond3) <= 0.01, report
    assert max(beyond2[:2]) <= 0.10, report
