"""The aided filter's heading is honest (issue 28): a wrong or changed magnetometer calibration is caught, the
published σ covers the heading error, the iron is learned, the yaw is reset to the GNSS yaw when needed.

Truth is the simulator's (scipy rotations in bench.vehicle_accuracy); runs are short and shared (module scope), and
read at 50 Hz (tests/support/thinned_ins.py: the estimates of the samples read are those of a run read at 200 Hz)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from ahrsd.core.estimate import EstimateFlags, HeadingState
from bench.vehicle_accuracy import (
    IRON_STEP_UT,
    honesty_figures,
    simulate_vehicle,
    tilt_heading_errors_deg,
)
from support.thinned_ins import run_ins_thinned

SECONDS = 240.0


TRUSTING_S = 60.0       # how long the old filter is run in the NEES test


def _first_seconds(run, seconds):
    """The run's samples before `seconds` (its fixes stay: those after the last sample are never fed)."""
    k = int(np.searchsorted(run.t_s, seconds))
    vel = None if run.truth_vel_ned_m_s is None else run.truth_vel_ned_m_s[:k]
    return dataclasses.replace(run, t_s=run.t_s[:k], gyro_rad_s=run.gyro_rad_s[:k], accel_m_s2=run.accel_m_s2[:k],
                               mag_ut=run.mag_ut[:k], truth_q_wxyz=run.truth_q_wxyz[:k], truth_vel_ned_m_s=vel)


@pytest.fixture(scope="module")
def uncalibrated_boat():
    return simulate_vehicle("boat", SECONDS, 2, None, mag="uncalibrated")


@pytest.fixture(scope="module")
def iron_step_boat():
    return simulate_vehicle("boat", SECONDS, 3, None, mag="iron-step")


@pytest.fixture(scope="module")
def iron_step_out(iron_step_boat):
    """(the run at the samples read, run_ins_detailed's dict there, the flags of every sample)"""
    thin = run_ins_thinned(iron_step_boat)
    return thin.run, thin.detailed(), thin.flags_every_sample


def test_heading_nees_under_a_wrong_calibration_is_not_overconfident(uncalibrated_boat):
    """The boat's raw field (tens of µT of non-symmetric iron, no calibration): the heading NEES e²/σ² sampled
    every 10 s after 30 s stays below the 99 % χ² bound of its mean, and ≤ 1 % of the samples are beyond 3σ.
    The heading state says MAGNETOMETER only once the iron is learned, and then honestly.
    The old filter (magnetometer trusted as calibrated, no monitor) says 0.4° while 30° off."""
    from scipy.stats import chi2    # here, not at the top: every collection of the suite would import scipy.stats

    thin = run_ins_thinned(uncalibrated_boat)
    run, honest = thin.run, thin.detailed()
    picks = np.searchsorted(run.t_s, np.arange(30.0, SECONDS, 10.0))
    hi = chi2.ppf(0.99, len(picks)) / len(picks)

    def mean_nees(out, at=picks):
        _, hdg = tilt_heading_errors_deg(out["q"], run.truth_q_wxyz[:len(out["q"])], run.declination_rad)
        e = np.radians(hdg[at])
        return float(np.mean(e ** 2 / out["sigma_yaw_rad"][at] ** 2))

    assert mean_nees(honest) < hi, (mean_nees(honest), hi)
    assert honesty_figures(run, honest, 30.0)["beyond_3sigma"] <= 0.01
    # "heading good" (MAGNETOMETER) from this magnetometer only once its iron is learned: never in the first
    # 60 s, when the raw field turns the heading by tens of degrees; afterwards only with σ below the trusted 3°
    # and the error within 3σ
    _, hdg = tilt_heading_errors_deg(honest["q"], run.truth_q_wxyz, run.declination_rad)
    good = honest["heading_state"] == int(HeadingState.MAGNETOMETER)
    sig_deg = np.degrees(honest["sigma_yaw_rad"])
    assert not np.any(good[run.t_s < 60.0])
    assert np.all(sig_deg[good] < 3.0) and np.all(np.abs(hdg[good]) <= 3.0 * sig_deg[good])
    # the old filter over the first 60 s only: its NEES there is already far beyond the bound (measured in
    # docs/testing.md), so the rest of the run would show nothing more
    early = picks[run.t_s[picks] < TRUSTING_S]
    trusting = run_ins_thinned(_first_seconds(uncalibrated_boat, TRUSTING_S), mag_calibration_sigma_rad=0.0,
                               heading_monitor=False, gnss_yaw=False).detailed()
    print(f"heading NEES: {mean_nees(honest):.2f} honest, {mean_nees(trusting, early):.0f} trusting "
          f"(first {TRUSTING_S:.0f} s), bound {hi:.2f}")
    assert mean_nees(trusting, early) > 10.0 * hi


def test_an_iron_step_is_learned_without_a_published_step(iron_step_boat, iron_step_out):
    """Calibrated boat; the hard iron moves by 9 µT half-way: the magnetometer is rejected, the iron learned (to
    1.5 µT per axis), the magnetometer re-enters, and the heading is within 0.5° RMS from 60 s after the step
    and none beyond 3σ. (The largest change of the published heading error within 0.1 s is reported by the
    bench, docs/estimator.md: it misses the issue's 0.5° while σ is raised after the rejection.)"""
    run, out, _ = iron_step_out
    t_step = 0.5 * SECONDS
    offset, cov = out["ins"].learned_iron()
    assert np.all(np.abs(offset - np.array(IRON_STEP_UT)) < 1.5), offset
    assert np.all(np.sqrt(np.diag(cov)) < 2.0)
    after = honesty_figures(run, out, t_step + 60.0)
    assert after["heading_rms"] < 0.5 and after["beyond_3sigma"] == 0.0, after
    state = out["heading_state"]
    assert np.any(state[(run.t_s > t_step) & (run.t_s < t_step + 30.0)] != int(HeadingState.MAGNETOMETER))
    assert state[-1] == int(HeadingState.MAGNETOMETER)


def test_without_iron_learning_the_magnetometer_stays_out(iron_step_boat):
    run = iron_step_boat
    out = run_ins_thinned(run, len(run.t_s), iron_learning=False).detailed()    # the last estimate only
    assert np.all(out["ins"].learned_iron()[0] == 0.0)
    assert out["heading_state"][-1] != int(HeadingState.MAGNETOMETER)


def test_sigma_is_raised_when_the_magnetometer_is_rejected(iron_step_boat, iron_step_out):
    """Within 2 s of the iron step the published yaw σ is raised to at least 3× its value before (the estimate
    has not moved yet: the heading error stays within 3σ throughout)."""
    run, out, flags = iron_step_out
    t_step = 0.5 * SECONDS
    before = out["sigma_yaw_rad"][(run.t_s > t_step - 5.0) & (run.t_s < t_step)].max()
    after = out["sigma_yaw_rad"][(run.t_s > t_step) & (run.t_s < t_step + 2.0)].max()
    assert after > 3.0 * before, (before, after)
    assert np.any(flags[iron_step_boat.t_s > t_step] & int(EstimateFlags.MAG_REJECTED))


def test_learned_iron_api_round_trips_and_refuses_garbage():
    from ahrsd.estimator.ins import Ins

    ins = Ins()
    ins.set_learned_iron([1.0, -2.0, 3.0], np.eye(3) * 4.0)
    off, cov = ins.learned_iron()
    assert np.allclose(off, [1.0, -2.0, 3.0]) and np.allclose(cov, np.eye(3) * 4.0)
    with pytest.raises(ValueError):
        ins.set_learned_iron([math.nan, 0.0, 0.0], np.eye(3))
    with pytest.raises(ValueError):
        ins.set_learned_iron([0.0, 0.0, 0.0], -np.eye(3))
    ins.reset_learned_iron()
    assert np.all(ins.learned_iron()[0] == 0.0)


def test_an_aided_magnetometer_update_never_moves_the_horizon():
    """After 60 s of the boat with GNSS (tilt–heading covariance far from zero), one magnetometer update with a
    field turned by 10° rotates the attitude about down only; with mag_moves_tilt it leans the horizon. Without
    a fix within gnss_timeout_s (dead reckoning: the heading-only row, as before the first fix) not even a
    trusted magnetometer's update (mag_moves_tilt, as ins sets it for one) moves the horizon (issue 29, item 5)."""
    from scipy.spatial.transform import Rotation

    from ahrsd.estimator import ins_core as core

    run = simulate_vehicle("boat", 60.0, 4, None)
    ins = run_ins_thinned(run, len(run.t_s)).ins       # the filter's state only: no estimate read
    P = ins._P
    assert abs(P[0, 2]) + abs(P[1, 2]) > 1e-3 * math.sqrt(P[0, 0] * P[2, 2])

    def tilt_of_one_update(moves_tilt: bool, outage: bool = False) -> float:
        x, P1, par = ins._x.copy(), ins._P.copy(), ins._par.copy()
        par["mag_moves_tilt"] = 1.0 if moves_tilt else 0.0
        if outage:      # the last fix fused longer than gnss_timeout_s ago: the GNSS no longer holds the tilt
            x["gnss_fused_t_s"] = x["t_last_s"] - par["gnss_timeout_s"] - 1.0
        par["mag_use"] = 1.0
        m = x["mag_last_ut"]
        x["mag_last_ut"] = Rotation.from_euler("z", 10.0, degrees=True).apply(m)
        q0 = x["q"].copy()
        x["mag"]["gate_open_s"] = 1.0   # the gate open (as after a new calibration): the update is applied
        core._mag_update(x, P1, par, 0.01, 0.0)
        d = (Rotation.from_quat(np.roll(x["q"], -1))
             * Rotation.from_quat(np.roll(q0, -1)).inv()).as_rotvec()
        assert abs(d[2]) > 1e-6      # the heading moved
        return float(np.hypot(d[0], d[1]))

    assert tilt_of_one_update(False) < 1e-12
    assert tilt_of_one_update(True) > 1e-7
    assert tilt_of_one_update(True, outage=True) < 1e-12


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_a_heading_far_off_is_reset_to_the_gnss_yaw_and_stays_honest(seed):
    """The boat at 33.9° S with the strong held-out vehicle iron, no calibration: the magnetometer heading starts
    ~120° off; the GNSS yaw becomes valid, the yaw is reset to it (flagged YAW_RESET) with the biases learned
    against the wrong yaw reverted and the velocity reset to the fix, and from 60 s on ≤ 1 % of the samples are
    beyond 3σ, the heading within 5° RMS (170 s). Without the reset the filter stays tens of degrees off with a
    small σ (seed 11: 95 % beyond 3σ); without the bias revert 18 % (seed 11), without the velocity reset 27 %
    (seed 12). The yaw σ held at the GNSS yaw's until a 5° GNSS yaw confirms the heading is not what keeps these
    seeds within 3σ (without it none of their samples is beyond 3σ either): test_gnss_yaw_alignment and the boat
    replays (test_gnss_yaw_set_sigma, test_heading_rejection_sigma) fail without it."""
    from bench.vehicle_accuracy import HONESTY_SITES

    site, iron = HONESTY_SITES["held-out"]
    thin = run_ins_thinned(simulate_vehicle("boat", 170.0, seed, site, mag="uncalibrated", iron=iron))
    f = honesty_figures(thin.run, thin.detailed(), 60.0)
    assert f["beyond_3sigma"] <= 0.01 and f["heading_rms"] < 5.0, f
    assert thin.ins.yaw_resets >= 1
    assert np.any(thin.flags_every_sample & int(EstimateFlags.YAW_RESET))     # set on one estimate


def test_a_confident_wrong_calibration_is_held_honest_after_its_rejection():
    """A calibration that claims 0.5° but misses (12, −8, 0) µT of the boat's hard iron (what a user gets from a
    calibration done without the battery in): once the GNSS has shown it wrong (30 s on), ≥ 99 % of the
    published headings are within 3σ of the simulator's truth. The error reaches into the σ: with the published σ
    halved a quarter of the samples are beyond 3σ (mutation ins-published-yaw-sigma-half)."""
    from ahrsd.simulation import SensorErrors, open_stream

    run = simulate_vehicle("boat", 150.0, 3, None)
    soft_inverse = np.linalg.inv(open_stream("boat", rate_hz=200.0, seed=3, errors=SensorErrors.adis16405(3))
                                 .errors.soft_iron)
    run = dataclasses.replace(run, mag_ut=np.ascontiguousarray(run.mag_ut - soft_inverse @ np.array([12.0, -8.0, 0.0])),
                              mag_calibration_sigma_rad=math.radians(0.5))
    thin = run_ins_thinned(run)
    assert thin.ins.heading_report().mag_rejections >= 1
    assert honesty_figures(thin.run, thin.detailed(), 30.0)["beyond_3sigma"] <= 0.01
