"""The lean a speed change leaves in mekf's accelerometer-levelled tilt is in its published 1σ (turn_lean.py
`track_accel_push`): the summed levelling corrections reconstruct the tilt error a first-order levelling takes
from a braking manoeuvre (worked here without the filter), and mekf without GNSS on the simulated car (it speeds
up and brakes) keeps its roll, pitch and heading errors against the simulator's truth (scipy) within 3σ."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ahrsd.estimator.turn_lean import TURN_LEAN_DTYPE, track_accel_push
from bench.unaided_sigma import one_run


def test_the_summed_corrections_are_the_lean_the_levelling_took():
    """A levelling with gain k = P/(P + R) corrects its tilt e toward the apparent vertical, which braking at
    2 m/s² for 4 s leans by φ = a/g: e ← e + k(φ − e + n). Its innovation φ − e + n is all the filter sees. The
    sum of k·ν follows e: within the noise before the braking, and within what it forgets of the lean over the
    4 s (ACCEL_PUSH_MEMORY_S = 30 s: (1 − e^(−4/30))·|φ|) plus the noise during and after it."""
    rng = np.random.default_rng(3)
    u = np.zeros(1, dtype=TURN_LEAN_DTYPE)[0]
    dt, p, r = 0.01, 1e-6, 2e-4                     # k = 0.005 per update: the error follows φ in ≈ 2 s
    k = p / (p + r)
    t = np.arange(0.0, 30.0, dt)
    phi = np.where((t > 5.0) & (t < 9.0), -2.0 / 9.81, 0.0)          # along north: a tilt about east
    e = np.empty(len(t))
    push = np.empty(len(t))
    e_now = 0.0
    for i in range(len(t)):
        nu = phi[i] - e_now + rng.normal(0.0, 0.01)
        track_accel_push(u, nu, 0.0, k, k, dt, False)       # the innovation on δθ_E (nu_n), its gain k
        e_now += k * nu
        e[i], push[i] = e_now, u["accel_push_e_rad"]
    assert np.max(np.abs(e)) > math.radians(9.0)     # the lean was taken
    assert np.max(np.abs(push[t < 5.0])) < math.radians(0.1)
    forgotten = (1.0 - math.exp(-4.0 / 30.0)) * 2.0 / 9.81
    assert np.max(np.abs(push - e)) < forgotten + math.radians(0.1), (np.max(np.abs(push - e)), forgotten)
    assert np.max(np.abs(push - e)) > 0.5 * forgotten     # it does forget (the bound is not loose)


@pytest.mark.parametrize("seed", [13])
def test_mekf_without_gnss_on_a_car_that_speeds_up_and_brakes_is_honest(seed):
    """Car seed 13, 120 s, from 30 s: every axis within 3σ on ≥ 99 % of the samples (without the term: roll,
    pitch and heading 10 / 11 / 13 % beyond; 180 s: 21 / 8 / 19 %, bench/unaided_sigma.py)."""
    # the calibration right (no error injected), the daemon's 5° "heading good" limit, the circle check on
    _, _, _, rms, sigma_deg, beyond_pct = one_run(("car", seed, 120.0, 30.0, "mekf", None, math.radians(5.0), True))[:6]
    assert np.all(beyond_pct <= 1.0), (rms, sigma_deg, beyond_pct)
