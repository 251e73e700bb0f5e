"""The accelerometer z axis's lean towards x and y (its misalignment elements m_zx, m_zy) as ins's error states
(ins_core.E_AZ_LEAN): the mechanisation removes m_zx f_x + m_zy f_y from the z axis, and the GNSS learns the lean
from the vehicle's horizontal acceleration seen in the vertical channel (docs/estimator.md "The accelerometer z
axis's lean as states"). Checked against the simulator's misalignment (simulation/errors.py: f_meas = (I + diag(s)
+ M) f + b, so the z axis reads m_zx f_x + m_zy f_y more), with the truth track and fixes of tests/ins_truth.py."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from ahrsd.estimator import ins_core as core
from ahrsd.estimator.ins import Ins
from ahrsd.simulation import SensorErrors
from ahrsd.simulation.vehicles import Leg, TrackVehicle
from ins_truth import DECLINATION, gnss_fixes, run_ins, simulated_run

M_ZX_RAD = math.radians(0.3)     # a 3σ draw of the simulator's 0.1° (seed 31's car has +0.316°)
M_ZY_RAD = math.radians(-0.2)
LEAN = slice(core.E_AZ_LEAN, core.E_AZ_LEAN + core.N_ACC_Z_LEAN)


def _errors_with_lean_only(gyro_misaligned: bool) -> SensorErrors:
    """The ADIS16405 draw of seed 31 with the accelerometer's only misalignment the z axis's lean, and the gyro's
    misalignment kept or removed."""
    errors = SensorErrors.adis16405(31)
    m = np.zeros((3, 3))
    m[2, 0] = M_ZX_RAD
    m[2, 1] = M_ZY_RAD
    errors = errors.replace(accel_misalignment_rad=m)
    if not gyro_misaligned:
        errors = errors.replace(gyro_misalignment_rad=np.zeros((3, 3)))
    return errors


def _run(scenario, seconds, errors, **params):
    """ins over the simulated run with truth fixes: (its final lean estimate, its lean σ, the prior σ). The lean
    learns from the fixes at the end of the run (not held, as it is with the x/y bias while the heading is unknown)."""
    run = simulated_run(scenario, seconds, errors=errors)
    est = Ins(declination_rad=DECLINATION, **params)
    run_ins(est, run, gnss_fixes(run.truth), estimates_every=len(run.truth.t_s))   # the final state only: no estimate
    assert est._par["accel_bias_learn"] > 0.5
    lean = est._x["accel_z_lean_rad"].copy()
    sigma = np.sqrt(np.diag(est._P)[LEAN])
    return lean, sigma, est.params.accel_axes_tilt_sigma_rad


@pytest.fixture(scope="module")
def car_leaning():
    """240 s of the simulated car (accelerations from rest to 20 m/s, braking at 0.64 g, 0.4 g turns) whose gyro
    has no misalignment and the filter no gyro-misalignment states: on a level vehicle the x gyro's m_xz makes a
    body-fixed pitch error survive the turns, so with those states the lean and the pitch share what the vertical
    channel sees by their priors (docs/estimator.md); without them the turns fix the tilt and the lean is
    observable."""
    return _run("car", 240.0, _errors_with_lean_only(False), init_gyro_misalignment_sigma_rad=0.0)


def test_an_accelerating_car_learns_the_lean(car_leaning):
    lean, sigma, prior = car_leaning
    truth = np.array([M_ZX_RAD, M_ZY_RAD])
    # learned: at least half of each element (the sign right), within 3σ of the filter's own σ, σ well below the prior
    for k in range(2):
        assert lean[k] * truth[k] > 0.5 * truth[k] ** 2, (np.degrees(lean), np.degrees(truth))
        assert abs(lean[k] - truth[k]) < 3.0 * sigma[k], (np.degrees(lean), np.degrees(sigma))
    assert sigma[0] < 0.7 * prior, np.degrees(sigma)


@dataclass
class _StraightLeg(TrackVehicle):
    """A vehicle on one straight, level leg at a steady 15 m/s (no acceleration, no turn, no climb)."""

    name = "straight-leg"
    description = "straight, level, steady 15 m/s"
    default_iron = None

    def __post_init__(self):
        self._set_legs([Leg(600.0)], 15.0, 30.0)

    def euler_rad(self, t_s):
        t = np.asarray(t_s, dtype=float)
        return self.course_rad(t), np.zeros_like(t), np.zeros_like(t)


def test_a_straight_steady_leg_leaves_the_lean_at_its_prior():
    # the lean is seen only through f_x, f_y: with neither (no acceleration, level) nothing separates it from the
    # tilt and the vertical bias, so it stays where it started, with its prior σ, though the sensor has 0.3°
    # (the heading taken as known from the start, so that nothing holds the lean: only what the fixes tell it)
    lean, sigma, prior = _run(_StraightLeg(), 90.0, _errors_with_lean_only(True), accel_bias_needs_heading=False)
    np.testing.assert_array_less(np.abs(lean), math.radians(0.01))
    np.testing.assert_array_less(0.99 * prior, sigma)
