"""Without a trusted magnetometer calibration the aided filter's yaw is set to the first valid GNSS yaw
(HeadingConfirmation.alignment_due, InsParams.yaw_align_to_gnss_yaw); until a GNSS yaw confirms the heading the
published yaw σ covers the distance to the GNSS yaw bank (HeadingConfirmation.unconfirmed_yaw_sigma) — the heading
state says UNKNOWN, not a heading 100° off with a 10° σ — and the horizontal accelerometer bias is held
(accel_bias_needs_heading).
Truth: the simulator's attitude (scipy rotations in bench.vehicle_accuracy)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.core.estimate import EstimateFlags, HeadingState
from ahrsd.core.sample import SampleFlags, make_sample
from ahrsd.estimator.ins import Ins, InsParams
from ahrsd.simulation import SensorErrors
from bench.vehicle_accuracy import (CALIBRATED_SIGMA_RAD, HONESTY_SITES, estimates_in_arrival_order, simulate_vehicle,
                                    tilt_heading_errors_deg)

SECONDS = 20.0


def _run(mag: str, seed: int = 14, seconds: float = SECONDS, place=HONESTY_SITES["held-out"], **params) -> dict:
    """The held-out car (strong non-symmetric iron, 33.9° S; or `place`: (site, iron)) fed sample by sample; per
    sample the published heading error (deg) and σ (deg), the heading state, the GNSS yaw's validity, flags and the
    reset count, the published pitch error and σ (deg) and the x accelerometer bias error (m/s², against the
    simulator's turn-on bias)."""
    site, iron = place
    errors = SensorErrors.adis16405(seed)
    run = simulate_vehicle("car", seconds, seed, site, mag=mag, iron=iron, errors=errors)
    est = Ins(declination_rad=run.declination_rad, lever_arm_m=run.lever_arm_m,
              mag_calibration_sigma_rad=run.mag_calibration_sigma_rad, **params)
    n = len(run.t_s)
    q, sig, state, valid, flags, resets = (np.zeros((n, 4)), np.zeros(n), np.zeros(n, int), np.zeros(n, bool),
                                           np.zeros(n, int), np.zeros(n, int))
    bias_learns = np.zeros(n, bool)
    pitch_sigma, bias_x_err = np.zeros(n), np.zeros(n)
    for k, e in estimates_in_arrival_order(est, run, run.fixes):
        q[k], sig[k], state[k], flags[k], resets[k] = (e.q_wxyz, math.degrees(e.sigma_rpy_rad[2]),
                                                       int(e.heading_state), int(e.flags), est.yaw_resets)
        valid[k] = e.integrity is not None and e.integrity.gsf_valid
        bias_learns[k] = est._par["accel_bias_learn"] > 0.5
        pitch_sigma[k] = math.degrees(e.sigma_rpy_rad[1])
        bias_x_err[k] = est._x["accel_bias_m_s2"][0] - errors.accel_bias_m_s2[0]
    _, hdg = tilt_heading_errors_deg(q, run.truth_q_wxyz, run.declination_rad)
    pitch = [Rotation.from_quat(a[:, [1, 2, 3, 0]]).as_euler("ZYX", degrees=True)[:, 1] for a in (q, run.truth_q_wxyz)]
    return {"t": run.t_s, "err": hdg, "sigma": sig, "state": state, "gsf_valid": valid, "flags": flags,
            "resets": resets, "bias_learns": bias_learns, "alignments": est.gnss_yaw_alignments,
            "pitch_err": pitch[0] - pitch[1], "pitch_sigma": pitch_sigma, "bias_x_err": bias_x_err}


@pytest.fixture(scope="module")
def uncalibrated():
    return _run("uncalibrated")


def test_the_yaw_is_set_to_the_first_valid_gnss_yaw(uncalibrated):
    """The magnetometer starts the car ~125° off. At the first valid GNSS yaw (10 s) the yaw is reset to it
    (YAW_RESET) and is within 8° from then on, inside 3σ. Broken (the alignment dropped): the filter is still tens
    of degrees off when the GNSS yaw is valid, and its σ does not cover it."""
    o = uncalibrated
    aided = (o["flags"] & int(EstimateFlags.GNSS_AIDED)) != 0
    first = int(np.argmax(o["gsf_valid"]))
    assert o["gsf_valid"][first] and 5.0 < o["t"][first] < 15.0
    assert abs(o["err"][first - 1]) > 20.0                 # the magnetometer's heading, pulled part way in
    after = slice(first, None)
    assert o["resets"][first] >= 1 and np.any(o["flags"][first:first + 5] & int(EstimateFlags.YAW_RESET))
    assert o["alignments"] == 1            # counted as the planned alignment (the daemon says INFO, not WARNING)
    assert np.all(np.abs(o["err"][after]) < 8.0), np.abs(o["err"][after]).max()
    assert np.all(np.abs(o["err"][after]) <= 3.0 * o["sigma"][after])
    assert np.all(aided[after])


def test_until_then_the_published_sigma_covers_the_error_and_the_heading_is_unknown(uncalibrated):
    """Aided, GNSS yaw not yet valid: the filter's own σ (10–20°) does not cover its 95–128° error; the published
    σ (the GNSS yaw bank's, with the distance to it) does, and the heading state is UNKNOWN (σ above 15°).
    Broken (no floor on the published σ): the error is beyond 3σ and the state is not UNKNOWN throughout."""
    o = uncalibrated
    aided = (o["flags"] & int(EstimateFlags.GNSS_AIDED)) != 0
    before = aided & ~np.maximum.accumulate(o["gsf_valid"])
    assert before.sum() > 1000                             # ~10 s of 200 SPS
    assert np.all(np.abs(o["err"][before]) <= 3.0 * o["sigma"][before])
    assert np.all(o["state"][before] == int(HeadingState.UNKNOWN))


def test_a_trusted_calibration_is_not_replaced_by_the_gnss_yaw():
    """A calibrated magnetometer (σ 0.5°) holds the heading from the start: no reset to the GNSS yaw, the published
    σ is the filter's (below 3° once converged)."""
    o = _run("calibrated")
    assert CALIBRATED_SIGMA_RAD < math.radians(3.0)
    assert o["resets"][-1] == 0
    assert o["alignments"] == 0
    assert np.all(o["sigma"][o["t"] > 5.0] < 3.0)


def test_the_horizontal_accel_bias_waits_for_the_gnss_yaw(uncalibrated):
    """The horizontal accelerometer bias does not learn while the heading is the magnetometer's (aided, before
    the first valid GNSS yaw) and learns again once the car's GNSS yaw (σ 2–5°, below the 10° of
    accel_bias_gsf_sigma_rad) agrees with the aligned heading. Broken (never released): still held at 20 s."""
    o = uncalibrated
    aided = (o["flags"] & int(EstimateFlags.GNSS_AIDED)) != 0
    first = int(np.argmax(o["gsf_valid"]))
    assert not np.any(o["bias_learns"][aided & (np.arange(len(o["t"])) < first)])
    assert np.all(o["bias_learns"][o["t"] > o["t"][first] + 5.0])


@pytest.mark.parametrize("off", [{"mag_enabled": False}, {"heading_monitor": False}, {"gnss_yaw": False},
                                 {"yaw_align_to_gnss_yaw": False}])
def test_without_the_heading_checks_the_published_sigma_is_the_filters(off):
    """Nothing would ever confirm the heading: no floor on the published σ (it would stay at π for good)."""
    assert math.isnan(Ins(**off)._heading.confirmation.unconfirmed_sigma_rad)
    assert Ins()._heading.confirmation.unconfirmed_sigma_rad == pytest.approx(math.pi)


def test_a_gnss_held_heading_is_not_reported_unknown_while_its_sigma_is_a_few_degrees(uncalibrated):
    """After the alignment the car's heading is held by the GNSS (σ 2.5–6°, inside 3σ: the first test): the heading
    state says GNSS_ONLY or LEARNING, not UNKNOWN — the yaw σ above INITIALISING's 3° alone no longer makes it
    unknown (the README's boat said "unknown" for 118 of 200 s while within 5°). Broken (INITIALISING → UNKNOWN
    again): UNKNOWN from 10.1 to 12.5 s and 18.3–24 s."""
    o = uncalibrated
    first = int(np.argmax(o["gsf_valid"]))
    # a better state is published once it held InsParams.heading_state_hold_s (estimator/heading_state_hold.py)
    held = (o["t"] > o["t"][first] + 1.0 + InsParams().heading_state_hold_s) & (o["sigma"] <= 15.0)
    assert held.sum() > 700
    assert np.all(o["state"][held] != int(HeadingState.UNKNOWN)), np.unique(o["t"][held & (o["state"] == 0)].round())
    assert np.any((o["sigma"][held] > 3.0) & (o["state"][held] != int(HeadingState.MAGNETOMETER)))


def test_the_alignment_drops_the_gyro_bias_learned_against_the_magnetometer():
    """The default-site boat without calibration: before its GNSS yaw is valid (~28 s) the filter follows the raw
    magnetometer, whose error changes by tens of degrees as the boat turns, and its vertical gyro bias takes up that
    rate (about 0.5 °/s off the simulator's). Nothing had confirmed the heading, so the alignment puts the biases
    back to their start-up values: right after it the vertical gyro bias is within 0.15 °/s of the simulator's.
    Broken (the alignment keeps the biases the agreement check took as confirmed): 0.6 °/s off. The magnetometer's
    turning (mag_rotation.py) is off here: its windows, which run before the alignment once the tilt is known
    whatever the heading's σ, measure that bias from the field's turning, which no iron changes, and would leave
    nothing wrong for the alignment to drop."""
    from ahrsd.simulation import SensorErrors

    seed = 2
    run = simulate_vehicle("boat", 32.0, seed, None, mag="uncalibrated")
    true_bias_z = SensorErrors.adis16405(seed).gyro_bias_rad_s[2]
    est = Ins(declination_rad=run.declination_rad, lever_arm_m=run.lever_arm_m,
              mag_calibration_sigma_rad=run.mag_calibration_sigma_rad, mag_rotation_gyro_bias=False)
    off_before = off_after = None
    fi = 0
    for k, t in enumerate(run.t_s):
        while fi < len(run.fixes) and run.fixes[fi].extra["t_rx_s"] <= t:
            aligned = est.gnss_yaw_alignments
            off = abs(math.degrees(est.gyro_bias_rad_s[2] - true_bias_z))
            est.update_gnss(run.fixes[fi])
            fi += 1
            if est.gnss_yaw_alignments > aligned:
                off_before, off_after = off, abs(math.degrees(est.gyro_bias_rad_s[2] - true_bias_z))
        est.update(make_sample(t, run.gyro_rad_s[k], run.accel_m_s2[k], run.mag_ut[k], flags=SampleFlags.NEW_DATA))
    assert off_before is not None, "no alignment in the run"
    assert off_before > 0.3                 # the scenario does test it: the bias was learned wrong
    assert off_after < 0.15, (off_before, off_after)


def test_the_tilt_levelled_under_the_wrong_yaw_is_relevelled_not_learned_as_bias():
    """The uncalibrated car at Nairobi (an iron never tuned on) starts ~100° off and accelerates away at 3–4 m/s²
    with its horizontal accelerometer bias held: the GNSS acceleration projected through that yaw leans the pitch
    5° by the alignment (10 s), with a 0.65° σ. The alignment gives the tilt the σ of the lean its yaw step implies
    for the specific force the tilt was levelled against (|f_h|·|sin Δψ| over |f_d|, at most the 5° a fix assumes
    when it first sets the velocity: YawReset.relevel): the next fixes re-level it. Broken (the tilt
    keeps its small variance, or the lean taken as 0) they put the 5° into the just-released x bias (154 mm/s² off,
    measured) and the pitch stays 0.6° off (RMS) to 30 s; relevelled, 82 mm/s² and 0.38°."""
    o = _run("uncalibrated", seed=31, seconds=30.0, place=("-1.29,36.82", "unseen"))
    assert o["alignments"] == 1
    t_align = o["t"][np.argmax(o["resets"] > 0)]
    assert 8.0 < t_align < 12.0, t_align
    after = o["t"] >= t_align
    assert np.max(np.abs(o["bias_x_err"][after])) < 0.12, np.max(np.abs(o["bias_x_err"][after]))
    settled = o["t"] >= t_align + 3.0
    rms = float(np.sqrt(np.mean(np.square(o["pitch_err"][settled]))))
    assert rms < 0.5, rms
    assert np.all(np.abs(o["pitch_err"][settled]) <= 3.0 * o["pitch_sigma"][settled])
