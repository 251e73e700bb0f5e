"""The iron is learned only against a heading the GNSS holds, and a heading no GNSS yaw has confirmed is not held
(issue 28: an honest heading σ; docs/gnss.md "The iron learned against an unconfirmed heading (plane31)").

Without a trusted magnetometer calibration the filter's yaw is pulled in by the GNSS velocity through linearised
updates whose variance shrinks faster than the error; until a GNSS yaw confirms it the published σ is at least the
GNSS yaw bank's plus the distance to it (HeadingConfirmation.unconfirmed_yaw_sigma). On the uncalibrated plane at
Singapore (iron `unseen`, seed 42) a 30 s steady turn leaves the filter's yaw 4–11° off at a variance of 1–2°
while the published σ says 13–180°: an iron learned there against the filter's own variance takes that yaw error in
(its heading offset 5° off at a stated 1.5°), and once the learning ends the magnetometer holds the heading 1–2°
off at a σ of 0.25–0.45° (21.9 % of the samples beyond 3σ over 600 s).

Truth is the simulator's: the true attitude of the simulated plane against the published one (scipy)."""

from __future__ import annotations

import numpy as np

from ahrsd.estimator.ins import Ins
from bench.vehicle_accuracy import estimates_in_arrival_order, simulate_vehicle, tilt_heading_errors_deg

SITE = "1.35,103.82"        # Singapore: dip −13°, H 41 µT
SEED = 42
SECONDS = 150.0             # past the first turn after the iron learning ended (130–140 s) on the unfixed filter
EVERY = 8


def _published(run) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every EVERY-th sample's time, published quaternion and yaw σ (rad), each fix offered where it arrives."""
    est = Ins(declination_rad=run.declination_rad, lever_arm_m=run.lever_arm_m,
              mag_calibration_sigma_rad=run.mag_calibration_sigma_rad)
    keep = np.arange(0, len(run.t_s), EVERY)
    q = np.empty((len(keep), 4))
    sigma = np.empty(len(keep))
    for k, e in estimates_in_arrival_order(est, run, run.fixes):
        if k % EVERY == 0:
            q[k // EVERY], sigma[k // EVERY] = e.q_wxyz, e.sigma_rpy_rad[2]
    return run.t_s[keep], q, sigma


def test_an_iron_learned_only_against_a_confirmed_heading_keeps_the_plane_within_its_sigma():
    run = simulate_vehicle("plane", SECONDS, SEED, SITE, mag="uncalibrated", iron="unseen")
    t, q, sigma = _published(run)
    _, heading_deg = tilt_heading_errors_deg(q, run.truth_q_wxyz[np.arange(0, len(run.t_s), EVERY)],
                                             run.declination_rad)
    honest = t >= 30.0
    beyond = np.abs(heading_deg[honest]) > 3.0 * np.degrees(sigma[honest])
    # issue 28's target: |error| ≤ 3σ on at least 99 % of the samples after the first 30 s (the unfixed filter:
    # 18 % here, every one of them after its iron learning ended at 105 s)
    assert np.mean(beyond) <= 0.01, (np.mean(beyond), t[honest][beyond][:5])
    # and the heading itself: the unfixed filter's magnetometer held it 1.2–2.2° off from 130 s
    late = t >= 100.0
    assert np.sqrt(np.mean(heading_deg[late] ** 2)) < 0.5
