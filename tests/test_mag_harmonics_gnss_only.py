"""The magnetometer heading-error harmonics (estimator/mag_harmonics.py) learn only while the GNSS holds the tilt
(ins_core._fuse_mag_heading). Levelled by the accelerometer in turns, the vertical leans towards the turn's centre,
a lean that turns with the heading and, through the dip, reads as a once-per-turn heading error: taken by the
states for the calibration's, it would stay in them after the turns and turn the heading by it on the next
straight leg.

What "not learned" means here: the states take no correction, so their variance (Ins.covariance, δe_m, indices
24–28) never falls below the prior they started from: the calibration's stated σ² split as the module docstring
says (the constant f0·σ², the once-per-turn pair ⅔ of the rest each, the twice-per-turn pair ⅓ each), computed
here from that rule. With the GNSS holding the tilt the same turns do teach them: the once-per-turn
terms' variance falls below 0.7 of the prior (the positive control: the run can observe them).

The boat is the simulator's `level-turns` (9 ± 4 °/s at 2 m/s, a 1–2.6° lean, tests/test_ins_turn_lean.py),
its magnetometer calibrated exactly (tests/ins_truth.py), the calibration stating 0.54°."""

from __future__ import annotations

import math

import numpy as np
import pytest
from ins_truth import DECLINATION, gnss_fixes, simulated_run, with_fixes_offered

from ahrsd.core.sample import SampleFlags, make_sample
from ahrsd.estimator.ins import Ins, InsParams

SECONDS = 60.0
STATED_SIGMA_RAD = math.radians(math.hypot(0.5, 0.2))
HARMONICS = slice(24, 29)        # δe_m: c0, c1, s1, c2, s2 (Ins.covariance's docstring)


def prior_variances_rad2(sigma_rad, offset_share):
    """The documented split of σ² (estimator/mag_harmonics.py): c0 f0·σ²; c1, s1 each ⅔ of the rest; c2, s2 each
    ⅓ of the rest — so that their sum at any heading, f0 + 2·(1 − f0)/3 + (1 − f0)/3 (cos² + sin² = 1 per pair), is σ²."""
    var = sigma_rad ** 2
    rest = (1.0 - offset_share) * var
    return np.array([offset_share * var, 2.0 / 3.0 * rest, 2.0 / 3.0 * rest, rest / 3.0, rest / 3.0])


def harmonic_variances_rad2(aided: bool) -> np.ndarray:
    """The smallest variance each harmonic state had over a run (checked every 0.1 s)."""
    run = simulated_run("level-turns", SECONDS, rate_hz=200.0, seed=3)
    t = run.truth.t_s
    fixes = gnss_fixes(run.truth) if aided else []
    ins = Ins(declination_rad=DECLINATION)
    ins.set_mag_calibration_sigma(STATED_SIGMA_RAD)
    smallest = np.full(5, np.inf)
    for k in with_fixes_offered(t, fixes, ins.update_gnss):
        ins.update(make_sample(t[k], run.gyro[k], run.accel[k], run.mag[k], flags=SampleFlags.NEW_DATA))
        if k % 20 == 0:
            smallest = np.minimum(smallest, np.diag(ins.covariance)[HARMONICS])
    return smallest


def test_the_prior_split_sums_to_the_stated_variance_at_any_heading():
    p = prior_variances_rad2(STATED_SIGMA_RAD, InsParams().mag_harmonic_offset_share)
    assert p[0] + p[1] + p[3] == pytest.approx(STATED_SIGMA_RAD ** 2)


def test_levelled_turns_teach_the_harmonics_nothing():
    prior = prior_variances_rad2(STATED_SIGMA_RAD, InsParams().mag_harmonic_offset_share)
    smallest = harmonic_variances_rad2(aided=False)
    assert np.all(smallest >= prior * (1.0 - 1e-9)), np.degrees(np.sqrt(smallest)) / np.degrees(np.sqrt(prior))


def test_turns_with_the_gnss_holding_the_tilt_teach_the_once_per_turn_terms():
    prior = prior_variances_rad2(STATED_SIGMA_RAD, InsParams().mag_harmonic_offset_share)
    smallest = harmonic_variances_rad2(aided=True)
    assert np.all(smallest[1:3] < 0.7 * prior[1:3]), np.sqrt(smallest / prior)
