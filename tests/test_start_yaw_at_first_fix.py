"""The first fix of a start levelled on the specific force couples the magnetometer's yaw to the tilt the fix widens
(estimator/ins.py `_widen_for_turn_lean` → `_couple_start_yaw_to_tilt`, ins_start.py `couple_yaw_to_tilt`; docs/gnss.md
"Session 42 (wmmdef)"). A boat rolling in waves while it turns levels its first sample on a specific force that leans
by the turn's and the waves' acceleration (3° at seed 0); the magnetometer reads the heading at that tilt, off by
tan(dip) times the tilt error along the horizontal field (4.5° at the 56.5° dip here). The first fix widens the tilt
to what levelling cannot exclude (ins_core `_reset_from_fix`, 5°), but the yaw kept the 0.34° its heading-only
updates gave it: the GNSS then moved the tilt and left the yaw 12.9σ off (seed 0, main 4965a930). Truth: the
simulator's attitude, compared with scipy (tests/ins_truth.py `attitude_error_ned`)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ahrsd.estimator.ins import DEFAULT_INS_PARAMS, Ins
from ahrsd.simulation.errors import SensorErrors

from ins_truth import DECLINATION, attitude_error_ned, gnss_fixes, run_ins, simulated_run

FIRST_FIX_S = 0.6        # gnss_fixes' first fix (valid at 0.5 s, 0.095 s late) is fused at 0.595 s


def _boat_start(seed: int, seconds: float):
    """tests/test_ins.py's NEES run (level turns, sensor errors drawn from the filter's priors, a field without
    calibration error: σ_cal = 0) for `seconds`: the attitude error (NED rad) and the attitude covariance at every
    10th sample, with their times."""
    p = DEFAULT_INS_PARAMS
    rng = np.random.default_rng(seed)
    err = SensorErrors.ideal().replace(
        gyro_bias_rad_s=rng.normal(0.0, math.radians(0.1), 3),
        gyro_noise_density_rad_s_rthz=p.gyro_noise_rad_s_sqrt_hz,
        gyro_scale=rng.normal(0.0, p.init_gyro_scale_sigma, 3),
        gyro_misalignment_rad=rng.normal(0.0, p.init_gyro_misalignment_sigma_rad, (3, 3)) * (1.0 - np.eye(3)),
        accel_bias_m_s2=rng.normal(0.0, 0.05, 3),
        accel_noise_density_m_s2_rthz=p.accel_noise_m_s2_sqrt_hz,
        mag_noise_density_ut_rthz=0.125 / math.sqrt(819.2))
    run = simulated_run("level-turns", seconds, rate_hz=200.0, seed=seed, errors=err)
    est = Ins(declination_rad=DECLINATION, mag_calibration_sigma_rad=0.0, mag_heading_noise_rad=p.mag_heading_noise_rest_rad)
    res = run_ins(est, run, gnss_fixes(run.truth, seed=seed + 10), cov_every=10, estimates_every=10)
    ks = sorted(res.cov)
    e = attitude_error_ned(res.q_true, run.truth.q_wxyz)[ks]
    sigma = np.sqrt(np.array([np.diag(res.cov[k])[:3] for k in ks]))
    return run.truth.t_s[ks], e, sigma


@pytest.mark.parametrize("seed", [0, 2, 3])
def test_a_boat_start_s_yaw_stays_within_3_sigma_from_its_first_fix(seed):
    """Seeds whose start levels 2–3° off (the yaw 2.3–4.5° off, 6–13σ before the first fix: the kernel's
    heading-only row, left as it is): from the first fix to 10 s the yaw and the tilt stay within 3σ (measured
    at most 1.5σ; main 4965a930: yaw 6.6–12.9σ, tilt 3.6–6.6σ over 0.6–2 s)."""
    t, e, sigma = _boat_start(seed, 10.0)
    before = t < FIRST_FIX_S - 0.05
    assert np.max(np.abs(e[before, 2])) > math.radians(2.0)      # the start this test is about: its yaw is off
    after = t >= FIRST_FIX_S
    z = np.abs(e[after]) / sigma[after]
    assert np.max(z[:, 2]) < 3.0, (np.max(z[:, 2]), t[after][np.argmax(z[:, 2])])
    assert np.max(z[:, :2]) < 3.0, np.max(z[:, :2])
