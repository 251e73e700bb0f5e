"""A new magnetometer calibration starts the heading-error harmonic states again from its own prior
(estimator/mag_harmonics.py; Ins.set_mag_calibration_sigma, the daemon's calibration swap). What the states
learned is the old calibration's error; carried over, it would be subtracted from a magnetometer that no longer
has it, with the small variance the learning left, so the heading would be off by the old error while its σ says
it is good.

The boat (tests/ins_truth.py, seed 12) runs 90 s on calibration A, whose error is a function of the magnetic
heading (constant 1.68°, once per turn 2.4°, twice per turn 0.4°; it states 2.4°), while the GNSS holds the tilt and
the harmonics learn it. Then calibration B is swapped in: it has no error (the field is the truth's, plus 0.1 µT of
noise) and states 0.3°. After the swap (from 2 s on) the heading must be within 3σ_B = 0.9° RMS and within 3 of its
published σ on at least 99 % of the samples. The magnetometer is built from the truth, independently of the
estimator, as in tests/test_mag_calibration_harmonics.py."""

from __future__ import annotations

import math

import numpy as np
from ins_truth import DECLINATION, gnss_fixes, rot, run_ins, simulated_run, tilt_heading_errors_deg
from scipy.spatial.transform import Rotation

from ahrsd.estimator.ins import Ins
from ahrsd.simulation import DEFAULT_SITE

SECONDS, SWAP_S, SETTLE_S = 180.0, 90.0, 2.0
A_STATED_RAD = math.radians(2.4)
B_STATED_RAD = math.radians(0.3)
MAG_NOISE_UT = 0.1


def calibration_a_error_rad(psi_rad):
    return math.radians(1.68) + math.radians(2.4) * np.cos(psi_rad - math.radians(270.0)) \
        + math.radians(0.4) * np.sin(2.0 * psi_rad)


def test_a_new_calibration_does_not_inherit_the_error_learned_for_the_old_one():
    run = simulated_run("boat", SECONDS, rate_hz=200.0, seed=12)
    truth = rot(run.truth.q_wxyz)
    t = run.truth.t_s - run.truth.t_s[0]
    psi_mag = truth.as_euler("ZYX")[:, 0] - DECLINATION
    e = np.where(t < SWAP_S, calibration_a_error_rad(psi_mag), 0.0)
    field_ned = np.asarray(DEFAULT_SITE.earth_field().ned_ut, dtype=float)
    turned = Rotation.from_euler("z", e[:, None]).apply(field_ned)
    run.mag = truth.inv().apply(turned) + np.random.default_rng(5).normal(0.0, MAG_NOISE_UT, (len(t), 3))

    ins = Ins(declination_rad=DECLINATION, mag_calibration_sigma_rad=A_STATED_RAD)
    sigma_yaw = []
    real_update = ins.update
    swap_index = int(np.searchsorted(t, SWAP_S))     # the first sample calibrated by B

    def update(sample):
        if len(sigma_yaw) == swap_index:
            ins.set_mag_calibration_sigma(B_STATED_RAD)
        est = real_update(sample)
        sigma_yaw.append(float(est.sigma_rpy_rad[2]))
        return est

    ins.update = update
    res = run_ins(ins, run, gnss_fixes(run.truth))
    _, heading_deg = tilt_heading_errors_deg(res.q_mag, run.truth.q_wxyz)
    after = t >= SWAP_S + SETTLE_S
    err, sigma = heading_deg[after], np.degrees(np.asarray(sigma_yaw))[after]
    rms = float(np.sqrt(np.mean(err ** 2)))
    beyond = float(np.mean(np.abs(err) > 3.0 * sigma))
    assert rms <= 3.0 * math.degrees(B_STATED_RAD), f"heading RMS {rms:.2f}° after the swap"
    assert beyond <= 0.01, f"{100 * beyond:.1f} % beyond 3σ after the swap (median σ {np.median(sigma):.2f}°)"
