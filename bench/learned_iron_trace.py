"""The learned iron against the simulator's truth over a run: what its heading error is, what its prior says, and
how much of it the learning window's yaw error explains (docs/gnss.md "The learning window's yaw error in the
learned iron's prior (iron30)").

Runs `ins` as `bench/heading_timeline.py` does (same vehicle, site, iron and case) and prints, every `--every`
seconds: the filter's true heading error and its own yaw 1σ; whether the iron is being learned; the learned
magnetometer's true heading error on a level vehicle at 16 headings (the learned iron applied to the
noise-free field of the simulated magnetometer, WMM at the site) — its mean over the headings (c0, the part a
common yaw error makes) and its worst; and the 1σ of c0 that the harmonic states' prior gives, from the
learner's covariance alone and with the learning window's yaw share (estimator/learned_iron.py).

    python bench/learned_iron_trace.py --site=-31.95,115.86 --iron held-out --seeds 31 --seconds 900
    python bench/learned_iron_trace.py --case iron-step --seeds 15
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.vehicle_accuracy import (HONESTY_IRONS, IRON_STEP_AT, IRON_STEP_UT, estimates_in_arrival_order,  # noqa: E402
                                    honesty_iron, honesty_site, honesty_site_arg, simulate_vehicle,
                                    tilt_heading_errors_deg)

HEADINGS_RAD = np.linspace(0.0, 2.0 * math.pi, 16, endpoint=False)


def _level(yaw_rad: float) -> np.ndarray:
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def true_mag_model(errors, case: str, t_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(A, b): the noise-free magnetometer `ins` is fed, m = A·B_body + b, at time t (simulation/errors.py's model,
    less the calibration simulate_vehicle applies for the calibrated cases)."""
    hard = np.asarray(errors.hard_iron_ut, dtype=float)
    step = np.asarray(errors.hard_iron_step_ut, dtype=float) if t_s >= errors.hard_iron_step_t_s else np.zeros(3)
    soft = np.asarray(errors.soft_iron, dtype=float)
    if case == "uncalibrated":
        return soft, hard + step
    return np.eye(3), np.linalg.solve(soft, step)


def learned_level_errors_rad(learner, a_true, b_true, field_ned) -> np.ndarray:
    """The learned magnetometer's heading error (inferred − true) on a level vehicle at HEADINGS_RAD."""
    out = np.empty(len(HEADINGS_RAD))
    ref = math.atan2(field_ned[1], field_ned[0])
    for i, psi in enumerate(HEADINGS_RAD):
        c = _level(psi)
        m = a_true @ (c.T @ field_ned) + b_true
        horiz = c @ learner.corrected(m)
        rotated = math.atan2(horiz[1], horiz[0]) - ref     # the field turned by this: the heading read turns back
        out[i] = -math.remainder(rotated, 2.0 * math.pi)
    return out


def c0_sigma_rad(learner, cov, field_ned) -> float:
    from ahrsd.estimator.mag_harmonics import prior_from_heading_rows

    rows = learner.level_heading_rows(field_ned, HEADINGS_RAD)
    return math.sqrt(max(prior_from_heading_rows(rows, HEADINGS_RAD, cov)[0, 0], 0.0))


def trace(scenario: str, case: str, seed: int, site_label: str, iron_label: str | None, seconds: float,
          every_s: float) -> None:
    from ahrsd.estimator.ins import Ins
    from ahrsd.simulation import DEFAULT_SITE, SensorErrors, Site, open_stream
    from ahrsd.estimator import ins_core as core

    site, iron = honesty_site(site_label, iron_label)
    run = simulate_vehicle(scenario, seconds, seed, site, mag=case, iron=iron)
    errors = SensorErrors.adis16405(seed)
    if case == "iron-step":
        errors = errors.replace(hard_iron_step_ut=IRON_STEP_UT, hard_iron_step_t_s=IRON_STEP_AT * seconds)
    stream = open_stream(scenario, rate_hz=200.0, seed=seed, site=Site.parse(site) if site else DEFAULT_SITE,
                         errors=errors, vehicle_iron=honesty_iron(iron))
    truth_errors, field_ned = stream.errors, np.asarray(stream.earth_field.ned_ut, dtype=float)
    est = Ins(declination_rad=run.declination_rad, lever_arm_m=run.lever_arm_m,
              mag_calibration_sigma_rad=run.mag_calibration_sigma_rad)
    print(f"{scenario} {case} seed {seed} at {site_label} ({iron} iron), {seconds:.0f} s: "
          "t s | heading err ° | filter yaw σ ° | published σ ° | GNSS yaw σ ° | learning | mag fused | learned c0 err ° | worst ° | "
          "c0 σ: learner ° | + window yaw ° | worst heading σ: learner ° | offset σ: learner ° | offset held (not learned against the yaw)")
    next_t = every_s
    learning_was = False
    for k, e in estimates_in_arrival_order(est, run, run.fixes):
        t = run.t_s[k]
        learning = bool(est._heading.monitor.learning)
        if t < next_t and not (learning_was and not learning):
            learning_was = learning
            continue
        ended = learning_was and not learning
        learning_was = learning
        if t >= next_t:
            next_t += every_s
        _, hdg = tilt_heading_errors_deg(np.asarray(e.q_wxyz)[None], run.truth_q_wxyz[k][None], run.declination_rad)
        yaw_sigma = math.degrees(math.sqrt(max(est._P[core.E_YAW, core.E_YAW], 0.0)))
        gsf_var = est._heading.gnss_yaw()[1]
        sigmas = (f"{yaw_sigma:5.2f} | {math.degrees(e.sigma_rpy_rad[2]):5.2f} | "
                  f"{math.degrees(math.sqrt(gsf_var)) if math.isfinite(gsf_var) else math.nan:5.2f}")
        learner = est._iron
        fused = 'yes' if est._par["mag_use"] > 0.5 else 'no '
        if learner.updates == 0:
            print(f"{t:7.1f} | {hdg[0]:+6.2f} | {sigmas} | {'yes' if learning else 'no '} | {fused} | (nothing learned)")
            continue
        a_true, b_true = true_mag_model(truth_errors, case, t)
        errs = np.degrees(learned_level_errors_rad(learner, a_true, b_true, field_ned))
        own = math.degrees(c0_sigma_rad(learner, learner.cov, field_ned))
        with_share = math.degrees(c0_sigma_rad(learner, learner.cov + est._learned_iron.yaw_share.cov(), field_ned))
        worst_sigma = math.degrees(learner.level_heading_sigma_rad(field_ned))
        offset_sigma = math.degrees(math.sqrt(learner.offset_heading_variance(field_ned)))
        print(f"{t:7.1f} | {hdg[0]:+6.2f} | {sigmas} | {'yes' if learning else 'no '} | {fused} | "
              f"{np.mean(errs):+6.2f} | {errs[np.argmax(np.abs(errs))]:+6.2f} | {own:5.2f} | {with_share:5.2f} | "
              f"{worst_sigma:5.2f} | {offset_sigma:5.2f} | {'yes' if learner.offset_held else 'no'}"
              + ("   <- learning ended" if ended else ""))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default="boat")
    ap.add_argument("--case", default="uncalibrated", choices=("uncalibrated", "iron-step"))
    ap.add_argument("--site", default="held-out", type=honesty_site_arg)
    ap.add_argument("--iron", default=None, choices=HONESTY_IRONS)
    ap.add_argument("--seeds", type=int, nargs="+", default=[31])
    ap.add_argument("--seconds", type=float, default=600.0)
    ap.add_argument("--every", type=float, default=30.0, help="print every this many seconds (default 30)")
    args = ap.parse_args(argv)
    for seed in args.seeds:
        trace(args.scenario, args.case, seed, args.site, args.iron, args.seconds, args.every)
    return 0


if __name__ == "__main__":
    sys.exit(main())
