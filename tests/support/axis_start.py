"""A start of ins levelled on a steady turn's rotation axis, taken from the simulator (estimator/ins_start.py
`levelling_force`): the run and a fresh filter for it, checked to level on the axis (else the case is not tested)."""

from __future__ import annotations

import numpy as np

from ahrsd.estimator.ins import Ins
from ahrsd.estimator.ins_start import levelling_force
from bench.vehicle_accuracy import simulate_vehicle


def axis_levelled_start(scenario: str, seconds: float, seed: int, site: str, start_s: float):
    """(run, ins) for `scenario` from `start_s` at `site` ("LAT,LON"), calibrated magnetometer; asserts the first
    sample levels on the rotation axis."""
    run = simulate_vehicle(scenario, seconds, seed, site, mag="calibrated", start_s=start_s)
    est = Ins(declination_rad=run.declination_rad, lever_arm_m=run.lever_arm_m,
              mag_calibration_sigma_rad=run.mag_calibration_sigma_rad)
    f, w = run.accel_m_s2[0], run.gyro_rad_s[0]
    level = levelling_force(f, w, 3.0 * est.params.init_accel_bias_sigma_m_s2, est.params.init_gyro_bias_sigma_rad_s)
    assert not np.array_equal(level, f), "the start did not level on the axis: the case is not tested"
    return run, est
