"""The constant heading offset from GNSS course (calibration/mag/course_offset.py) against courses made from the
exact vector sum of the vehicle's velocity through the water and a current (not the linearised model)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ahrsd.calibration.mag.course_offset import fit_course_offset

DEG = math.pi / 180.0


def legs(headings_deg, leg_s=20.0, turn_s=10.0, rate_hz=20.0):
    """True heading of a vehicle holding each heading for leg_s, turning smoothly to the next in turn_s."""
    t_all, psi_all = [], []
    t = 0.0
    for h0, h1 in zip(headings_deg, list(headings_deg[1:]) + [headings_deg[-1]]):
        tl = np.arange(0.0, leg_s, 1.0 / rate_hz)
        t_all.append(t + tl)
        psi_all.append(np.full(tl.size, h0 * DEG))
        t += leg_s
        tt = np.arange(0.0, turn_s, 1.0 / rate_hz)
        d = ((h1 - h0 + 180.0) % 360.0) - 180.0
        t_all.append(t + tt)
        psi_all.append((h0 + d * (1 - np.cos(np.pi * tt / turn_s)) / 2) * DEG)
        t += turn_s
    t = np.concatenate(t_all)
    psi = np.unwrap(np.concatenate(psi_all))
    return t, psi, np.gradient(psi, t)


def courses(t, psi_true, water_speed_m_s=2.0, current_ne=(0.0, 0.0), noise_deg=0.5, rate_hz=5.0, seed=3,
            latency_error_s=0.0):
    """Fixes at rate_hz: course and speed of v = V·(cos ψ, sin ψ) + c, with noise; `latency_error_s`: the
    stamped time of validity is that much later than the true one."""
    rng = np.random.default_rng(seed)
    tf = np.arange(t[0] + 1.0, t[-1] - 1.0, 1.0 / rate_hz)
    p = np.interp(tf, t, psi_true)
    vn = water_speed_m_s * np.cos(p) + current_ne[0]
    ve = water_speed_m_s * np.sin(p) + current_ne[1]
    chi = np.arctan2(ve, vn) + rng.normal(0.0, noise_deg * DEG, tf.size)
    return tf + latency_error_s, chi % (2 * math.pi), np.hypot(vn, ve)


EIGHT = [0, 45, 90, 135, 180, 225, 270, 315]


def test_offset_and_current_separated_over_headings_all_round():
    t, psi, rate = legs(EIGHT)
    offset_deg = 1.7                            # the magnetometer reads 1.7° low: true = measured + A
    tf, chi, v = courses(t, psi, current_ne=(0.3, -0.2))
    fit = fit_course_offset(tf, chi, v, np.nan, t, psi - offset_deg * DEG, rate)
    assert fit.refused is None and fit.current_ne_m_s is not None
    print(f"\nA {fit.offset_deg:.3f} ± {fit.std_deg:.3f}°, current {np.round(fit.current_ne_m_s, 3)} m/s, "
          f"{fit.n_used} of {fit.n_offered} fixes")
    assert abs(fit.offset_deg - offset_deg) < max(4 * fit.std_deg, 0.1)
    assert fit.std_deg < 0.1
    assert np.allclose(fit.current_ne_m_s, (0.3, -0.2), atol=0.03)


def test_a_current_would_bias_an_offset_taken_as_the_plain_mean():
    """Why the current is fitted: on unevenly spread headings the mean course − heading is off by the drift."""
    t, psi, rate = legs([0, 30, 60, 90, 180, 270])
    tf, chi, v = courses(t, psi, current_ne=(0.0, 0.4), noise_deg=0.2)
    fit = fit_course_offset(tf, chi, v, np.nan, t, psi, rate)
    straight = np.interp(tf, t, np.abs(rate)) < 0.1 * DEG
    plain_mean = math.degrees(np.angle(np.mean(np.exp(1j * (chi - np.interp(tf, t, psi)))[straight])))
    assert abs(plain_mean) > 2.0
    assert abs(fit.offset_deg) < 0.15


def test_one_sided_headings_fit_the_offset_alone_and_say_so():
    t, psi, rate = legs([10, 60, 110])
    tf, chi, v = courses(t, psi)
    fit = fit_course_offset(tf, chi, v, np.nan, t, psi + 0.8 * DEG, rate)
    assert fit.refused is None and fit.current_ne_m_s is None
    assert any("cannot be separated" in n for n in fit.notes)
    assert abs(fit.offset_deg + 0.8) < 0.1


def test_turns_are_left_out_so_a_latency_error_does_not_bias_the_offset():
    """Fixes stamped 0.5 s late: in a 9 °/s turn that is 4.5° of heading; on the straight legs nothing."""
    t, psi, rate = legs(EIGHT, leg_s=10.0, turn_s=5.0)
    tf, chi, v = courses(t, psi, latency_error_s=0.5, noise_deg=0.2)
    fit = fit_course_offset(tf, chi, v, np.nan, t, psi, rate)
    assert abs(fit.offset_deg) < 0.1
    everything = fit_course_offset(tf, chi, v, np.nan, t, psi, rate, max_turn_rate_deg_s=90.0, window_s=0.1)
    assert abs(everything.offset_deg) > 0.5       # the gate is what removes it


def test_slow_or_few_fixes_are_refused_with_a_reason():
    t, psi, rate = legs(EIGHT)
    tf, chi, v = courses(t, psi, water_speed_m_s=0.5)
    fit = fit_course_offset(tf, chi, v, np.nan, t, psi, rate)
    assert fit.refused is not None and "speed never reached 1.0 m/s" in fit.refused
    assert math.isnan(fit.offset_deg)
    none = fit_course_offset([], [], [], [], t, psi, rate)
    assert none.refused == "no GNSS course received"
    tf, chi, v = courses(t, psi)
    few = fit_course_offset(tf[:5], chi[:5], v[:5], np.nan, t, psi, rate)
    assert few.refused is not None and "straight runs" in few.refused


def test_speed_accuracy_weights_and_scales_the_uncertainty():
    t, psi, rate = legs(EIGHT)
    tf, chi, v = courses(t, psi, noise_deg=0.5)
    good = fit_course_offset(tf, chi, v, 0.005, t, psi, rate)      # claims 0.14° course accuracy at 2 m/s
    assumed = fit_course_offset(tf, chi, v, np.nan, t, psi, rate)  # 0.5° assumed
    # the measured residual, not the claim, sets the 1σ when the claim is too optimistic
    assert good.std_deg == pytest.approx(assumed.std_deg, rel=0.3)
