"""A yaw reset sets the velocity to the fix's (ins_gnss_fusion.InsGnssFusion.reset_velocity_to_fix) at the fix's
time of validity. The reset
runs in the heading checks right after that fix's own update, which moved the velocity of the state and of the
history rows after the fix's time but not of the rows up to it; the velocity read at the fix's time must carry the
same step, or the reset keeps the update's step as a velocity error (docs/gnss.md, "The velocity a yaw reset sets").

The case (val27, reset28): the car, seed 31, at Nairobi with the unseen iron and no calibration. The raw
magnetometer holds the yaw ~110° off while the car starts; the GNSS velocity, rejected, is taken up by the
position updates and the tilt (~6° off by 10 s); at the first valid GNSS yaw (~10.1 s) the yaw is aligned. The
update of that fix moved the velocity by ~0.8 m/s; kept as an error it had the next velocities rejected for
seconds while the tilt drove the velocity off, and what was fused after that pulled the yaw +13° and then −11°
on the straight leg (the "overshoot"), dragging the vertical gyro bias thousands of °/h; the first turn then
stated that bias known while it was ~900 °/h off (heading beyond 3σ).
Truth: the simulator's velocity, attitude and turn-on gyro bias (SensorErrors.adis16405, the seed's draw; its
in-run Gauss–Markov part is tens of °/h, within the margins here)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ahrsd.estimator import ins_core as core
from ahrsd.estimator.ins import Ins
from ahrsd.simulation import SensorErrors
from bench.vehicle_accuracy import (estimates_in_arrival_order, honesty_site, simulate_vehicle,
                                    tilt_heading_errors_deg)

SECONDS = 48.0
SEED = 31
LEG_S = (10.0, 24.0)             # from the alignment to the first turn (24–33 s): a straight leg
AFTER_TURN_S = (25.0, SECONDS)   # from a second into the first turn to the end of the straight after it


@pytest.fixture(scope="module")
def car() -> dict:
    """Per sample: the horizontal velocity error (m/s), b_z's error and σ (°/h), the published heading error and
    σ (deg) and the yaw reset count; the start-up b_z σ (°/h)."""
    site, iron = honesty_site("-1.29,36.82", "unseen")
    run = simulate_vehicle("car", SECONDS, SEED, site, mag="uncalibrated", iron=iron)
    bz_true = SensorErrors.adis16405(SEED).gyro_bias_rad_s[2]
    est = Ins(declination_rad=run.declination_rad, lever_arm_m=run.lever_arm_m,
              mag_calibration_sigma_rad=run.mag_calibration_sigma_rad)
    n = len(run.t_s)
    q = np.zeros((n, 4))
    sig, vel_err, bz_err, bz_sig, resets = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n, int)
    rows_after_reset = None
    for k, e in estimates_in_arrival_order(est, run, run.fixes):
        q[k], sig[k], resets[k] = e.q_wxyz, math.degrees(e.sigma_rpy_rad[2]), est.yaw_resets
        if rows_after_reset is None and est.yaw_resets > 0:
            # the history the reset left (and this sample's row), oldest first: time, horizontal velocity
            n_rows = int(est._x["hist_count"])
            idx = (int(est._x["hist_newest"]) - np.arange(n_rows)[::-1]) % core.H_LEN
            rows_after_reset = (est._hist["t_s"][idx].copy(), est._hist["vel_ned_m_s"][idx, :2].copy(),
                                est._x["vel_ned_m_s"][:2].copy(), est._fusion.last_fix_velocity[0])
        vel_err[k] = float(np.hypot(*(est._x["vel_ned_m_s"][:2] - run.truth_vel_ned_m_s[k, :2])))
        bz_err[k] = math.degrees(est._x["gyro_bias_rad_s"][2] - bz_true) * 3600.0
        bz_sig[k] = math.degrees(math.sqrt(est._P[core.E_BG + 2, core.E_BG + 2])) * 3600.0
    _, hdg = tilt_heading_errors_deg(q, run.truth_q_wxyz, run.declination_rad)
    return {"t": run.t_s, "hdg": hdg, "sigma": sig, "vel_err": vel_err, "bz_err": bz_err, "bz_sig": bz_sig,
            "resets": resets, "alignments": est.gnss_yaw_alignments, "rows_after_reset": rows_after_reset,
            "bz_startup_sig": math.degrees(est.params.init_gyro_bias_sigma_rad_s) * 3600.0}


def test_the_case_is_the_one_described(car):
    """One alignment to the GNSS yaw, in the second after 10 s, with the velocity metres per second off before it
    (the GNSS velocities rejected against the magnetometer's yaw)."""
    o = car
    assert o["alignments"] == 1
    k = int(np.argmax(o["resets"] > 0))
    assert 10.0 <= o["t"][k] <= 11.0, o["t"][k]
    assert o["vel_err"][k - 1] > 2.0, o["vel_err"][k - 1]


def test_the_reset_velocity_is_the_fixs(car):
    """Right after the reset the velocity is the fix's (σ 0.05 m/s) carried on by the mechanisation over the fix's
    latency (0.1 s), which integrated the car's ~3 m/s² with the old attitude (yaw 24°, tilt 6° off: up to
    ~0.25 m/s): within 0.3 m/s of the truth. Broken (the update's step not added to the rows up to the fix's
    time, or added with the wrong sign): 0.7 m/s off and more."""
    o = car
    k = int(np.argmax(o["resets"] > 0))
    assert o["vel_err"][k] < 0.3, o["vel_err"][k]


def test_the_straight_leg_does_not_drag_the_vertical_gyro_bias(car):
    """On the straight leg after the reset (yaw unobservable but for the car's speed changes) the GNSS-only yaw
    corrections leave b_z within 1.4 × its start-up σ (1800 °/h) of the truth: measured 1246 °/h (1.06σ of its own
    σ) before tilt29, 1902 °/h (1.63σ) since the alignment gives the tilt, leaned 5° by the wrong yaw, a 6° σ to
    re-level in (Ins._relevel_after_wrong_yaw; the heading after the turn 1.75 → 0.90σ). Broken: the overshoot
    drags it up to ~4000 °/h off."""
    o = car
    leg = (o["t"] > LEG_S[0] + 0.5) & (o["t"] < LEG_S[1])
    assert np.abs(o["bz_err"][leg]).max() < 1.4 * o["bz_startup_sig"], np.abs(o["bz_err"][leg]).max()


def test_after_the_first_turn_b_z_and_the_heading_are_within_3_sigma(car):
    """From the first turn on b_z is within 3σ of the truth and the published heading within 3σ of its σ.
    Broken: b_z 430–1100 °/h off at a stated 150–335 °/h after the turn (4.2σ), the heading 3.8σ off."""
    o = car
    w = (o["t"] >= AFTER_TURN_S[0]) & (o["t"] <= AFTER_TURN_S[1])
    z_bz = np.abs(o["bz_err"][w]) / o["bz_sig"][w]
    assert z_bz.max() < 3.0, z_bz.max()
    z_hdg = np.abs(o["hdg"][w]) / o["sigma"][w]
    assert z_hdg.max() < 3.0, z_hdg.max()


def test_the_reset_leaves_the_velocity_history_continuous_from_the_fix(car):
    """The reset shifts the kept trajectory to the fix: from the row before the reset fix's time to the state, the
    rows it leaves have no jump a velocity cannot make (200 SPS: the car's ≤ 3 m/s² changes it ≤ 0.015 m/s a row),
    nor has the state against the newest row. (Older rows keep the jumps each earlier fix's update left at its own
    time: an update corrects the rows after its fix's time only.) Broken: the row at the fix's time and the next
    differ by the fix's own update (0.89 m/s) when the step is dropped, or when it is added to every row."""
    t_rows, v_rows, v_state, t_fix = car["rows_after_reset"]
    assert np.all(np.diff(t_rows) > 0.0)
    recent = t_rows >= t_fix - 0.006
    assert recent.sum() >= 20
    jumps = np.hypot(*np.diff(v_rows[recent], axis=0).T)
    assert jumps.max() < 0.1, (jumps.max(), t_rows[recent][1:][jumps.argmax()])
    assert float(np.hypot(*(v_state - v_rows[-1]))) < 0.1
