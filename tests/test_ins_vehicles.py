"""`ins` on the vehicle scenarios (boat, car, plane) at a place that is not the simulator's default, with the
simulator's receiver model: the accuracy targets, the 30 s outage in a turn, and what an accelerometer-levelled
filter does on the same data. One seed per vehicle (CI speed); bench/accuracy.py --vehicles runs more. The data,
the fixes and the error measures are the benchmark's (bench/vehicle_accuracy.py): truth from the simulator's
analytic trajectories, errors with scipy rotations, never the estimator's own maths. ins's estimates are read at
50 Hz (tests/support/thinned_ins.py: those of a run read at 200 Hz, at the samples read)."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pytest

from bench.vehicle_accuracy import (
    SETTLE_S,
    attitude_steps_deg,
    run_mekf,
    simulate_vehicle,
    tilt_heading_errors_deg,
)
from support.thinned_ins import run_ins_thinned

# 60° N, where the field dips 74°: the magnetometer's heading is 3.4× as sensitive to a tilt error as at the
# equator-ward default site, so a horizon error shows in the heading too
SITE = "60.17,24.94,20,2026-06-15"
SEED = 7            # not among the seeds the defaults were chosen on (1–3, default site)
SECONDS = 150.0     # the targets' runs: 120 s judged from SETTLE_S (30 s)
OUTAGE_SECONDS = 200.0   # the outage runs: the longest turn after 60 s, and 2 s after the return


def _rms(a) -> float:
    return float(np.sqrt(np.mean(np.square(a))))


@functools.lru_cache(maxsize=None)
def _run(vehicle, outage=False):
    return simulate_vehicle(vehicle, OUTAGE_SECONDS if outage else SECONDS, SEED, SITE, outage=outage)


def _errors(run, q):
    tilt, heading = tilt_heading_errors_deg(q, run.truth_q_wxyz, run.declination_rad)
    m = run.t_s >= SETTLE_S
    return tilt[m], heading[m]


@pytest.mark.parametrize("vehicle", ["boat", "car", "plane"])
def test_ins_meets_the_targets_where_a_levelling_filter_leans(vehicle):
    """ins with 5 Hz GNSS: tilt RMS ≤ 0.3°, true-heading RMS ≤ 0.5° (measured here over 30–150 s 0.10–0.16° and
    0.16–0.32°);
    an accelerometer-levelled filter on the same samples leans into the accelerations."""
    run = _run(vehicle)
    thin = run_ins_thinned(run)
    tilt, heading = _errors(thin.run, thin.detailed()["q"])
    assert _rms(tilt) <= 0.3 and _rms(heading) <= 0.5, (_rms(tilt), _rms(heading))
    assert tilt.max() < 1.0 and np.abs(heading).max() < 1.5, (tilt.max(), np.abs(heading).max())
    # a plain accelerometer-levelled filter (mekf without its acceleration-adaptive tilt noise) leans by
    # 2.1° / 10.2° / 14.3° (tilt RMS over 30–150 s); mekf as shipped leans less (2.10° / 0.50° / 0.67°, since it
    # levels a speed change at rest across the lean only, unturned_lean.py) but still about twice as much as ins or
    # more
    from ahrsd.estimator.mekf import Mekf

    q_plain, _ = Mekf(acc_adaptive_gain=0.0).run_batch(run.t_s, run.gyro_rad_s, run.accel_m_s2, run.mag_ut, None)
    tilt_plain, _ = _errors(run, q_plain)
    assert _rms(tilt_plain) > {"boat": 1.5, "car": 5.0, "plane": 8.0}[vehicle], _rms(tilt_plain)
    tilt_mekf, _ = _errors(run, run_mekf(run))
    assert _rms(tilt) < _rms(tilt_mekf) / 1.8, (_rms(tilt), _rms(tilt_mekf))


@pytest.mark.parametrize("vehicle", ["boat", "car", "plane"])
def test_30_s_outage_in_the_longest_turn_dead_reckons_within_the_targets(vehicle):
    """No fixes for 30 s from the start of the longest turn after 60 s: tilt ≤ 1°, heading ≤ 2° inside (measured
    ≤ 0.74° / 1.2° over 6 seeds × 3 sites), and the attitude moves < 0.5° within 1 s of the loss and of the
    return."""
    run = _run(vehicle, outage=True)
    t0, t1 = run.outage
    # the filter runs until 2 s after the return: the last check is the step within 1 s of it (the accuracy once
    # aided again is the first test's)
    k = np.searchsorted(run.t_s, t1 + 2.0)
    run = dataclasses.replace(run, t_s=run.t_s[:k], gyro_rad_s=run.gyro_rad_s[:k], accel_m_s2=run.accel_m_s2[:k],
                              mag_ut=run.mag_ut[:k], truth_q_wxyz=run.truth_q_wxyz[:k])
    thin = run_ins_thinned(run)
    run, q = thin.run, thin.detailed()["q"]
    tilt, heading = tilt_heading_errors_deg(q, run.truth_q_wxyz, run.declination_rad)
    inside = (run.t_s >= t0) & (run.t_s < t1)
    assert tilt[inside].max() <= 1.0 and np.abs(heading[inside]).max() <= 2.0, \
        (tilt[inside].max(), np.abs(heading[inside]).max())
    assert max(attitude_steps_deg(q, run.truth_q_wxyz, run.t_s, (t0, t1 + 0.1))) < 0.5


def test_heading_at_high_dip_does_not_inherit_the_tilt_error():
    """At 69.65° N (Tromsø, dip 78°) a tilt error along magnetic north turns the magnetometer's heading by
    tan(dip) ≈ 4.7 times as much. Aided, the magnetometer row carries that sensitivity, so the boat's heading stays
    within the target (measured 0.36° RMS over 30–150 s; 0.29° over 30–200 s; 0.63° with the heading-only row of
    the unaided filter)."""
    thin = run_ins_thinned(simulate_vehicle("boat", SECONDS, SEED, "69.65,18.96,10,2026-07-01"))
    tilt, heading = _errors(thin.run, thin.detailed()["q"])
    assert _rms(heading) <= 0.5 and _rms(tilt) <= 0.3, (_rms(heading), _rms(tilt))


def test_an_antenna_on_a_mast_is_within_the_targets_when_the_filter_is_told():
    """The boat's receiver antenna 1 m aft and 2 m above the IMU (LEVER_ARMS_M): in the waves it moves at tenths
    of a m/s the IMU does not. Told the lever arm ([gnss] lever_arm_m), ins stays within the targets; not told, its
    lever-arm check finds the antenna and, asked to (`lever_arm_adopt`, off by default), the filter adopts the fitted
    arm (estimator/lever_arm_fit.py) and is within the targets too (tilt / heading RMS at this seed over 30–150 s:
    0.15° / 0.25° told, not told 0.21° / 0.21° with the adoption; over 30–200 s 0.14° / 0.24° told, not told
    0.34° / 0.90° without the adoption, 0.16° / 0.21° with it)."""
    run = simulate_vehicle("boat", SECONDS, SEED, SITE, lever_arm=True)
    assert run.lever_arm_m == (-1.0, 0.0, -2.0)
    told = run_ins_thinned(run)
    tilt, heading = _errors(told.run, told.detailed()["q"])
    assert _rms(tilt) <= 0.3 and _rms(heading) <= 0.5, (_rms(tilt), _rms(heading))
    untold = run_ins_thinned(run, lever_arm_m=(0.0, 0.0, 0.0), lever_arm_adopt=True).detailed()
    tilt_untold, heading_untold = _errors(told.run, untold["q"])
    print(f"told {_rms(tilt):.2f}/{_rms(heading):.2f}, untold {_rms(tilt_untold):.2f}/{_rms(heading_untold):.2f}")
    fit = untold["ins"].lever_arm_fit()
    assert fit.arm_wrong and fit.arm_adopted, fit
    assert np.linalg.norm(fit.antenna_m((0.0, 0.0, 0.0)) - run.lever_arm_m) < 0.6, fit
    assert _rms(tilt_untold) <= 0.3 and _rms(heading_untold) <= 0.5, (_rms(tilt_untold), _rms(heading_untold))
