"""The learned iron includes the soft iron where the motion observes it (issue 28 item 2): a level vehicle that
turns sees the horizontal field rotate in the body frame, so the horizontal soft iron is learned; the vertical
field stays constant in the body frame, so the soft iron's third column is seen only together with the hard iron
and stays at its prior. Truth: the simulator's held-out vehicle iron (simulation/magnetic.py VehicleIron,
measured = soft_iron·B + hard_iron) and the WMM field at the held-out site, the attitude known."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.core.wmm import earth_field
from ahrsd.estimator.heading_monitor import IronLearner
from ahrsd.simulation import VehicleIron

FIELD_NED_UT = earth_field(-33.87, 151.21, 40.0).ned_ut        # the held-out site of bench/vehicle_accuracy.py
SOFT_PRIOR = 0.1


def _attitudes(n: int, bank_deg: float = 0.0, seed: int = 0):
    """C_bn (body → NED) of a vehicle turning through two full circles, rolling ±bank_deg as it goes."""
    rng = np.random.default_rng(seed)
    yaw = np.linspace(0.0, 4.0 * math.pi, n) + rng.normal(0.0, 0.01, n)
    roll = np.radians(bank_deg) * np.sin(np.linspace(0.0, 7.0 * math.pi, n))
    pitch = np.radians(bank_deg) * 0.5 * np.cos(np.linspace(0.0, 5.0 * math.pi, n))
    return Rotation.from_euler("ZYX", np.c_[yaw, pitch, roll]).as_matrix()


def _learn(soft_prior: float, bank_deg: float = 0.0, n: int = 720, noise_ut: float = 0.3):
    """Feed the learner the simulator's distorted field at known attitudes; return it and the truth."""
    iron = VehicleIron.held_out()
    rng = np.random.default_rng(1)
    learner = IronLearner(40.0, soft_prior)
    c_all = _attitudes(n, bank_deg)
    for c in c_all:
        m = iron.soft_iron @ (c.T @ FIELD_NED_UT) + iron.hard_iron_ut + rng.normal(0.0, noise_ut, 3)
        learner.update(m, c, FIELD_NED_UT, np.zeros((3, 3)), noise_ut, 1.0)
    return learner, iron


def _heading_errors_deg(learner, iron, bank_deg: float = 0.0):
    """Heading of the corrected field against the true magnetic heading, over every heading, and its predicted
    1σ (heading_variance), degrees."""
    err, sig = [], []
    for c in _attitudes(360, bank_deg, seed=5):
        m = iron.soft_iron @ (c.T @ FIELD_NED_UT) + iron.hard_iron_ut
        m_ned = c @ learner.corrected(m)
        err.append(math.degrees(math.atan2(m_ned[1], m_ned[0]) - math.atan2(FIELD_NED_UT[1], FIELD_NED_UT[0])))
        sig.append(math.degrees(math.sqrt(learner.heading_variance(c, m_ned))))
    err = (np.asarray(err) + 180.0) % 360.0 - 180.0
    return err, np.asarray(sig)


def test_a_level_turning_vehicle_learns_the_horizontal_soft_iron():
    """After two level circles the corrected field's heading is within 0.3° of the truth at every heading, and
    the predicted heading σ says so (below 0.3°: the hard iron and the third column, each poorly known, are known
    together); the learned horizontal 2×2 block and D_zx, D_zy match the simulator's soft iron."""
    learner, iron = _learn(SOFT_PRIOR)
    err, sig = _heading_errors_deg(learner, iron)
    assert np.max(np.abs(err)) < 0.3
    assert np.max(sig) < 0.3
    # what an accepted calibration may claim: the same worst level σ, though the hard iron alone is known to µT only
    assert math.degrees(learner.level_heading_sigma_rad(FIELD_NED_UT)) == pytest.approx(np.max(sig), rel=0.05)
    assert np.max(learner.sigma_ut[0:2]) / math.hypot(*FIELD_NED_UT[0:2]) > math.radians(2.0)
    np.testing.assert_allclose(learner.soft_iron[:, 0:2], iron.soft_iron[:, 0:2], atol=0.01)


def test_the_hard_iron_alone_leaves_a_heading_error_that_varies_with_heading():
    """The same vehicle learning only the hard iron (the soft-iron states dropped): the non-symmetric soft iron
    leaves a heading error of degrees that changes as the vehicle turns."""
    learner, iron = _learn(0.0)
    err, _ = _heading_errors_deg(learner, iron)
    assert np.max(err) - np.min(err) > 4.0


def test_what_a_level_vehicle_cannot_observe_stays_at_its_prior():
    """Level: the third column of D (times the constant vertical field) is inseparable from the hard iron, so
    its σ stays near the prior while the horizontal block's shrinks below a tenth of it. Banking ±30° makes it
    observable: its σ shrinks too."""
    level, _ = _learn(SOFT_PRIOR)
    s = level.soft_iron_sigma
    assert np.all(s[:, 2] > 0.5 * SOFT_PRIOR)
    assert np.all(s[:, 0:2] < 0.1 * SOFT_PRIOR)
    banked, iron = _learn(SOFT_PRIOR, bank_deg=30.0)
    assert np.all(banked.soft_iron_sigma[:, 2] < 0.2 * SOFT_PRIOR)
    np.testing.assert_allclose(banked.soft_iron, iron.soft_iron, atol=0.02)


def test_the_heading_sigma_covers_the_error_of_an_unobservable_part():
    """Learned level, then flown banked ±30°: the unobserved third column now turns the heading; the predicted
    heading σ (which carries the soft iron's covariance) covers the error at ≥ 99 % of attitudes."""
    learner, iron = _learn(SOFT_PRIOR)
    err, sig = _heading_errors_deg(learner, iron, bank_deg=30.0)
    assert np.max(np.abs(err)) > 0.3          # there is an error to cover
    assert np.mean(np.abs(err) <= 3.0 * sig) >= 0.99


def test_learned_iron_reset_and_restore_keep_the_soft_iron_at_its_prior():
    learner, _ = _learn(SOFT_PRIOR, n=100)
    learner.set(np.ones(3), np.eye(3) * 0.25)
    np.testing.assert_array_equal(learner.soft_iron, np.eye(3))
    np.testing.assert_allclose(learner.soft_iron_sigma, np.full((3, 3), SOFT_PRIOR))
    np.testing.assert_array_equal(learner.offset_ut, np.ones(3))
    with pytest.raises(ValueError):
        learner.set([math.nan, 0.0, 0.0], np.eye(3))


def test_ins_removes_the_learned_soft_iron_before_its_heading_update():
    """The simulated boat (default site, the simulator's own calibration applied), no GNSS (the magnetometer is
    ins's only heading reference), its field then distorted by an extra soft iron S: told S as learned soft iron,
    ins's heading follows the undistorted run's to within 0.05° RMS; not told, the non-symmetric S turns it by
    degrees."""
    from ahrsd.core.sample import SampleFlags, make_sample
    from ahrsd.estimator.ins import Ins
    from bench.vehicle_accuracy import simulate_vehicle, tilt_heading_errors_deg

    run = simulate_vehicle("boat", 90.0, 3, None)
    soft = VehicleIron.held_out().soft_iron
    headings = {}
    for case, s in (("undistorted", np.eye(3)), ("told", soft), ("not told", soft)):
        d = dataclasses.replace(run, mag_ut=np.ascontiguousarray(run.mag_ut @ s.T))
        est = Ins(declination_rad=d.declination_rad, mag_calibration_sigma_rad=math.radians(0.5))
        # every case has a learned iron (the identity where not told S): the same heading model in all three (a
        # calibration without one carries its error as harmonic states, estimator/mag_harmonics.py)
        est.set_learned_iron(np.zeros(3), np.eye(3) * 0.01, soft if case == "told" else np.eye(3), np.eye(9) * 1e-6)
        q = np.array([est.update(make_sample(t, g, a, m, flags=SampleFlags.NEW_DATA)).q_wxyz
                      for t, g, a, m in zip(d.t_s, d.gyro_rad_s, d.accel_m_s2, d.mag_ut)])
        headings[case] = tilt_heading_errors_deg(q, d.truth_q_wxyz, d.declination_rad)[1]

    def rms_from(case):
        diff = (headings[case] - headings["undistorted"] + 180.0) % 360.0 - 180.0
        return float(np.sqrt(np.mean(diff[run.t_s >= 10.0] ** 2)))

    assert rms_from("told") < 0.05
    assert rms_from("not told") > 2.0
