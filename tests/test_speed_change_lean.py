"""The lean a speed change leaves in mekf's accelerometer-levelled tilt is in its published 1σ (turn_lean.py
`track_accel_push`): the summed levelling corrections reconstruct the tilt error a first-order levelling takes
from a braking manoeuvre (worked here without the filter), the part of them the filter's own gyro bias learning
explains is taken out (`track_bias_learning`, against the identity it rests on, evaluated here in numpy), and
mekf without GNSS on the simulated car (it speeds up and brakes) keeps its roll, pitch and heading errors against
the simulator's truth (scipy) within 3σ; on the README tour's boat its heading 1σ no longer depends on the
sample it started on."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest

from ahrsd.calibration.heading_trust import calibration_heading_sigma_rad
from ahrsd.calibration.models import Calibration, MagModel
from ahrsd.core.sample import SampleFlags, make_sample
from ahrsd.estimator.mekf import Mekf
from ahrsd.estimator.turn_lean import (
    ACCEL_PUSH_MEMORY_S,
    TURN_LEAN_DTYPE,
    prior_share,
    track_accel_push,
    track_bias_learning,
)
from ahrsd.simulation import open_stream
from bench.unaided_sigma import Job, one_run


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
        track_accel_push(u, nu, 0.0, k, k, dt, True)      # the innovation on δθ_E (nu_n), its gain k
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
    _, _, _, rms, sigma_deg, beyond_pct = one_run(Job("car", seed, 120.0, 30.0, "mekf"))[:6]
    assert np.all(beyond_pct <= 1.0), (rms, sigma_deg, beyond_pct)


def test_mekf_without_gnss_on_a_car_that_stops_keeps_its_heading_within_3_sigma():
    """Car seed 12, 180 s, from 30 s: roll and heading within 3σ on ≥ 99 % of the samples. The sum takes out
    the bias learning only while it learns the bias's prior (`prior_share`); taking out every change of the
    bias, also those of a bias held at its steady state that follows what the levelling reads as bias, left
    pitch and heading 9 / 7.5 % beyond where the car stands still at the end. (Pitch is not asserted: there
    its error is the accelerometer's bias, 6.7 mg on x, which no term of the 1σ carries: 4.4 % beyond before,
    1.1 % now; docs/estimator.md.)"""
    _, _, _, rms, sigma_deg, beyond_pct = one_run(Job("car", 12, 180.0, 30.0, "mekf"))[:6]
    assert beyond_pct[0] <= 1.0 and beyond_pct[2] <= 1.0, (rms, sigma_deg, beyond_pct)


def test_the_bias_learning_is_taken_out_of_the_sum():
    """A level vehicle turning at 9 °/s whose gyro has a horizontal bias the levelling learns from zero (the
    start of a run), no lean at all: the error moves as ε ← ε + C (b − b̂) Δt + δθ, the levelling corrects
    δθ = k ν and learns δb̂ = k_b Cᵀ(−ν) from ν = −ε + n. The corrections alone sum to the drift they
    corrected, degrees of it; with the bias learning taken out the sum is, exactly, Σ w Δε − M (b − b̂(t))
    (w: the forgetting, M = Σ w C Δt), both evaluated here from the simulated error and the true bias: near
    nothing once the bias is learnt (25 s: 1.3° summed, 0.02° left)."""
    rng = np.random.default_rng(5)
    dt, k, kb, omega = 0.01, 0.02, 0.005, math.radians(9.0)
    keep = math.exp(-dt / ACCEL_PUSH_MEMORY_S)
    b_true = np.radians([0.6, -0.4, 0.05])           # init_bias_sigma_rad_s: 0.5 °/s
    raw = np.zeros(1, dtype=TURN_LEAN_DTYPE)[0]        # the sum as main had it: corrections only
    u = np.zeros(1, dtype=TURN_LEAN_DTYPE)[0]          # with the bias learning taken out
    eps = np.zeros(2)
    b_hat = np.zeros(3)
    sum_deps = np.zeros(2)
    m = np.zeros((2, 3))
    worst = 0.0
    for i in range(2500):
        yaw = omega * i * dt
        c = np.array([[math.cos(yaw), -math.sin(yaw), 0.0], [math.sin(yaw), math.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
        eps_before = eps.copy()
        eps = eps + (c @ (b_true - b_hat))[:2] * dt                 # propagation with b̂
        nu = -eps + rng.normal(0.0, 1e-3, 2)
        dtheta = k * nu
        db = kb * (c[:2].T @ -nu)
        eps = eps + dtheta
        b_hat = b_hat + db
        for rec in (raw, u):
            # δθ = k·v with v = (v_N, v_E): the innovation on δθ_E is v_E, the one on −δθ_N is −v_N
            track_accel_push(rec, nu[1], -nu[0], k, k, dt, True)
        track_bias_learning(u, dt, tuple(c.ravel()), True, db[0], db[1], db[2])
        sum_deps = keep * sum_deps + (eps - eps_before)
        m = keep * m + c[:2] * dt
        push = np.array([u["accel_push_n_rad"], u["accel_push_e_rad"]])
        worst = max(worst, float(np.max(np.abs(push - (sum_deps - m @ (b_true - b_hat))))))
    push_raw = np.array([raw["accel_push_n_rad"], raw["accel_push_e_rad"]])
    push = np.array([u["accel_push_n_rad"], u["accel_push_e_rad"]])
    assert worst < 1e-9, worst                                        # the identity, at every step
    assert np.max(np.abs(np.degrees(b_true - b_hat)[:2])) < 0.01     # the horizontal bias is learnt (z: level)
    assert np.linalg.norm(push_raw) > math.radians(1.0), np.degrees(push_raw)  # the drift it corrected
    assert np.linalg.norm(push) < math.radians(0.1), np.degrees(push)


def test_the_prior_share_of_a_steps_bias_learning():
    """Worked: variance 4 before the step, the walk adds 1, the updates leave 3: of the 2 learnt, 1 shrank what
    was unknown before (share 0.5); leaving 4 (steady state: the walk relearnt) 0; leaving 1 with no walk 1;
    no update (5 left) 0."""
    assert prior_share(4.0, 1.0, 3.0) == pytest.approx(0.5)
    assert prior_share(4.0, 1.0, 4.0) == 0.0
    assert prior_share(4.0, 0.0, 1.0) == 1.0
    assert prior_share(4.0, 1.0, 5.0) == 0.0


START_OFFSETS = (0, 3, 6, 12, 18, 24, 48, 96, 200)
RUN_S = 80.0        # the 1σ's peak is the hard turn at ~72.5 s after every start


@functools.lru_cache(maxsize=1)
def _tour_boat(n: int):
    """The first `n` samples of the README tour's boat (`level-turns` seed 0) as the filter's samples, its
    magnetometer calibrated right, the true yaw and the calibration's heading σ (rad): simulated once for every
    start (the simulator's stream is the same whatever the block length: a start `offset` samples in sees the
    samples a stream of its own would give)."""
    stream = open_stream("level-turns", seed=0)
    e = stream.errors
    blk = stream.next_block(n)
    soft_inv = np.linalg.inv(e.soft_iron)
    mag = (soft_inv @ (blk.mag_ut - e.hard_iron_ut).T).T
    samples = [make_sample(blk.t_s[i], blk.gyro_rad_s[i], blk.accel_m_s2[i], mag[i], flags=SampleFlags.NEW_DATA)
               for i in range(n)]
    cal = Calibration.identity().with_sensor("mag", MagModel(e.hard_iron_ut, soft_inv), method="test",
                                             heading_std_deg=0.09, offset_std_deg=0.09)
    q = blk.truth_q_wxyz
    yaw_true = np.arctan2(2.0 * (q[:, 0] * q[:, 3] + q[:, 1] * q[:, 2]), 1.0 - 2.0 * (q[:, 2] ** 2 + q[:, 3] ** 2))
    return samples, yaw_true, calibration_heading_sigma_rad(cal), stream.earth_field.declination_rad


def _heading_sigma_peak_and_beyond(offset: int, run_s: float) -> tuple[float, float]:
    """mekf on the README tour's boat (`level-turns` seed 0, its magnetometer calibrated right and stating
    0.09°, as bench/start_phase_sigma.py), started `offset` samples into the stream: the peak heading 1σ from 5 s
    on (deg) and the share of samples whose true-heading error (the simulator's) is beyond 3σ."""
    n = offset + int(run_s * 819.2)
    samples, yaw_true, heading_sigma_rad, decl = _tour_boat(max(START_OFFSETS) + int(RUN_S * 819.2))
    est = Mekf(declination_rad=decl)
    est.set_mag_calibration_sigma(heading_sigma_rad)
    # each step's quaternion and yaw 1σ kept as they are; the yaw is taken from the quaternions afterwards, in
    # numpy (the view's yaw_rad would call the estimator's Euler kernel once per sample)
    q = np.empty((n - offset, 4))
    sig = np.empty(n - offset)
    for j, i in enumerate(range(offset, n)):
        v = est.step(samples[i])
        q[j] = v.q_wxyz
        sig[j] = v.sigma_rpy_rad[2]
    t_s = np.array([s.t_s for s in samples[offset:n]])
    late = t_s - t_s[0] >= 5.0
    q, sig = q[late], sig[late]
    yaw = np.arctan2(2.0 * (q[:, 1] * q[:, 2] + q[:, 0] * q[:, 3]), 1.0 - 2.0 * (q[:, 2] ** 2 + q[:, 3] ** 2))
    err = np.remainder(yaw + decl - yaw_true[offset:n][late] + math.pi, 2.0 * math.pi) - math.pi
    return math.degrees(float(sig.max())), 100.0 * float(np.mean(np.abs(err) > 3.0 * sig))


@pytest.mark.slow    # nine starts of 80 s at 819.2 Hz: the file starts first under --dist loadfile (tests/conftest.py)
def test_the_heading_sigma_does_not_depend_on_the_start_sample():
    """The daemon's start lands anywhere in the chip's stream. Started 0…200 samples (0–0.24 s) in, the tour's
    boat did the same turns, and its heading 1σ's peak over 2 min (at the hard turn ~72.5 s in) moved 4.81–6.01° (1.20°) when the sum counted
    the gyro bias being learnt at the start as lean (tilt corrections of the drift before the bias was known);
    now 4.80–5.00° (0.21°), all at the same hard turn. The margin, 0.5°: with the speed change's sum left out of
    the 1σ altogether the peaks spread 0.17° (3.92–4.08°: the turn's lean and the noise of each start), and the
    sum may add a little to that, not the 1.2° the bias learning did. Each start runs 80 s, past that turn. In
    each start the heading stays within 3σ of the truth on every sample."""
    peaks = []
    for offset in START_OFFSETS:
        peak, beyond = _heading_sigma_peak_and_beyond(offset, RUN_S)
        assert beyond <= 1.0, (offset, peak, beyond)
        peaks.append(peak)
    assert max(peaks) - min(peaks) < 0.5, peaks
