"""ins and mekf without GNSS on the simulated vehicles that speed up, brake and turn (boat, car, plane): roll,
pitch and heading RMS against the simulator's truth, the median published 1σ and the share of samples beyond 3σ,
from --from-s on (the magnetometer calibrated, the default site, 200 Hz: bench/vehicle_accuracy.simulate_vehicle).

    .venv/bin/python bench/unaided_sigma.py --scenarios boat car plane --seeds 12 13 15 16 11 14 17

A wrong calibration that still claims its usual small σ (issue 28: the hard iron moved after calibrating, or a bad
fit accepted): `--hard-iron-error-ut 3 6 9` runs each case with the calibration's hard iron off by that much
horizontally in the body frame (direction `--error-direction-deg` from the body x axis), `--soft-iron-error 0.1`
with its x-axis scale off by that fraction. With either, both filters are told the calibration's figure as the
daemon tells them (`set_mag_calibration_sigma`), and the lines add the share of samples whose heading state is
MAGNETOMETER, the share where the daemon would say "heading good" (MAGNETOMETER, not initialising, σ ≤
`--good-sigma-deg`, the [outputs] heading_good_sigma_deg default, and the circle check not finding the calibration
wrong: daemon/heading_status.py), the share where the circle check finds it wrong (estimator/field_circle.py) and,
from the first sample it does, the heading's share beyond 3σ ("after the turns that reveal it"):

    .venv/bin/python bench/unaided_sigma.py --seeds 12 13 15 16 --hard-iron-error-ut 0 3 6 9

mekf then learns the hard iron the check finds and removes it from the field (estimator/field_circle_correction.py;
`--no-iron-correction`: only the σ widening, the filter before it); the lines end with the heading RMS from 60 s
after the first flag to the end and its share beyond 3σ there. `--iron-step` runs the vehicles calibrated whose hard
iron moves by bench/vehicle_accuracy.IRON_STEP_UT half-way (use --seconds 600); the flag is then the first after it,
and the lines add the heading RMS, σ median and share beyond 3σ from 120 s after the step to the end and the
published heading's largest change in 0.1 s (its error's: the vehicle's own turn removed). Every line with a
calibration given ends with the share of samples a learned correction is applied on and how often the circle
check's fit restarted after an iron moved (estimator/field_circle.py).
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
from multiprocessing import Pool
from pathlib import Path
from typing import NamedTuple

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.vehicle_accuracy import simulate_vehicle  # noqa: E402


def errors_rph(q_mag, q_truth, declination_rad) -> np.ndarray:
    """Roll and pitch error (the NED error rotation's horizontal part in the truth's heading frame) and heading
    error (its down part), rad, per sample (as bench/mekf_sigma.py)."""
    from scipy.spatial.transform import Rotation

    def rot(x):
        return Rotation.from_quat(np.concatenate([x[:, 1:], x[:, :1]], axis=1))

    r_true = rot(q_truth)
    e = (Rotation.from_rotvec([0.0, 0.0, declination_rad]) * rot(q_mag) * r_true.inv()).as_rotvec()
    c = r_true.as_matrix()
    yaw = np.arctan2(c[:, 1, 0], c[:, 0, 0])
    return np.stack([np.cos(yaw) * e[:, 0] + np.sin(yaw) * e[:, 1], -np.sin(yaw) * e[:, 0] + np.cos(yaw) * e[:, 1],
                     e[:, 2]], axis=1)


def wrong_calibration_field(mag_ut: np.ndarray, hard_error_ut: float, direction_rad: float,
                            soft_error: float) -> np.ndarray:
    """The calibrated field as a calibration wrong by a horizontal hard iron of `hard_error_ut` (body x–y, at
    `direction_rad` from x) and an x-axis scale error `soft_error` leaves it: m = (I + diag(soft_error, 0, 0))·(m_cal
    − Δb) (a calibration removing b + Δb instead of b leaves −Δb in the field)."""
    db = hard_error_ut * np.array([math.cos(direction_rad), math.sin(direction_rad), 0.0])
    return (mag_ut - db) * np.array([1.0 + soft_error, 1.0, 1.0])


class Job(NamedTuple):
    """One run: the vehicle, the estimator, and the calibration it is given (None: the right one)."""
    scenario: str
    seed: int
    seconds: float
    from_s: float
    estimator: str
    wrong: tuple | None = None
    good_sigma_rad: float = math.radians(5.0)     # the daemon's heading_good_sigma_deg default
    circle: bool = True
    correct: bool = True
    iron_step: bool = False


def one_run(job: Job) -> tuple:
    from ahrsd.core.estimate import EstimateFlags, HeadingState
    from ahrsd.core.sample import SampleFlags, make_sample
    from ahrsd.estimator.ins import Ins
    from ahrsd.estimator.mekf import Mekf

    from bench.vehicle_accuracy import IRON_STEP_AT

    scenario, seed, seconds, from_s, estimator, wrong, good_sigma_rad, circle, correct, iron_step = Job(*job)
    run = simulate_vehicle(scenario, seconds, seed, None, mag="iron-step" if iron_step else "calibrated")
    mag_ut = run.mag_ut if wrong is None else wrong_calibration_field(run.mag_ut, *wrong)
    n = len(run.t_s)
    q = np.full((n, 4), np.nan)
    sig = np.full((n, 3), np.nan)
    state = np.zeros(n, dtype=int)
    init = np.ones(n, dtype=bool)
    off_centre = np.zeros(n, dtype=bool)      # the circle check finds the calibration wrong (field_circle.py)
    corrected = np.zeros(n, dtype=bool)       # mekf applies a correction learned in turns
    restarts = 0                              # the check's fit restarted after its iron moved (field_circle.py)
    if estimator == "ins":
        est = Ins(declination_rad=run.declination_rad, mag_calibration_sigma_rad=run.mag_calibration_sigma_rad,
                  mag_field_circle_check=circle)
        step = est.update
    else:
        est = (Mekf(mag_field_circle_check=circle) if wrong is None
               else Mekf(mag_calibration_sigma_rad=run.mag_calibration_sigma_rad, mag_field_circle_check=circle,
                         mag_field_circle_correction=correct))
        step = est.update
    for k in range(n):
        e = step(make_sample(run.t_s[k], run.gyro_rad_s[k], run.accel_m_s2[k], mag_ut[k],
                             flags=SampleFlags.NEW_DATA))
        q[k] = e.q_wxyz
        sig[k] = e.sigma_rpy_rad
        state[k] = int(e.heading_state)
        init[k] = bool(e.flags & EstimateFlags.INITIALISING)
        fc = est.field_circle() if estimator == "mekf" else est.field_circle_check()
        off_centre[k] = fc is not None and fc.finds_wrong(run.mag_calibration_sigma_rad ** 2)
        corrected[k] = fc is not None and fc.corrected
        restarts = max(restarts, getattr(fc, "restarts", 0))
    ok = (run.t_s >= from_s) & np.all(np.isfinite(q), axis=1)
    err = errors_rph(q[ok], run.truth_q_wxyz[ok], run.declination_rad)
    s = sig[ok]
    rms = np.degrees(np.sqrt(np.mean(err ** 2, axis=0)))
    beyond = 100.0 * np.mean(np.abs(err) > 3.0 * s, axis=0)
    mag_state = state[ok] == int(HeadingState.MAGNETOMETER)
    good = mag_state & ~init[ok] & (s[:, 2] <= good_sigma_rad) & ~off_centre[ok]
    # after the turns that reveal a wrong calibration: from the first sample the circle check flags it on (after the
    # iron's step with --iron-step)
    t_ok = run.t_s[ok]
    revealed = np.cumsum(off_centre[ok] & (t_ok >= (IRON_STEP_AT * seconds if iron_step else 0.0))) > 0
    t_flag = float(t_ok[np.argmax(revealed)]) if revealed.any() else np.nan
    settled = t_ok >= t_flag + 60.0
    after = (100.0 * np.mean(np.abs(err[revealed, 2]) > 3.0 * s[revealed, 2]) if revealed.any() else np.nan, t_flag,
             np.degrees(np.sqrt(np.mean(err[settled, 2] ** 2))) if settled.any() else np.nan,
             100.0 * np.mean(np.abs(err[settled, 2]) > 3.0 * s[settled, 2]) if settled.any() else np.nan)
    step = _after_the_step(t_ok, err[:, 2], s[:, 2], IRON_STEP_AT * seconds) if iron_step else None
    moved = (100.0 * np.mean(corrected[ok]), restarts)
    return (scenario, seed, estimator, rms, np.degrees(np.median(s, axis=0)), beyond, wrong,
            100.0 * np.mean(mag_state), 100.0 * np.mean(good), 100.0 * np.mean(off_centre[ok]), after, step, moved)


def _after_the_step(t_s, err_rad, sigma_rad, t_step_s, from_s=120.0, every_s=0.1):
    """The iron step's figures: heading RMS, σ median and the share beyond 3σ from `from_s` after the step to the
    end (°, °, %), and the published heading's largest change in `every_s` over the run (its error's change: the
    vehicle's own turn removed by the truth), °."""
    late = t_s >= t_step_s + from_s
    dt = float(np.median(np.diff(t_s)))
    k = max(1, int(round(every_s / dt)))
    change = np.abs(np.angle(np.exp(1j * (err_rad[k:] - err_rad[:-k]))))
    return (np.degrees(np.sqrt(np.mean(err_rad[late] ** 2))), np.degrees(np.median(sigma_rad[late])),
            100.0 * np.mean(np.abs(err_rad[late]) > 3.0 * sigma_rad[late]), np.degrees(change.max()))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", nargs="+", default=["boat", "car", "plane"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[12, 13, 15, 16])
    ap.add_argument("--estimators", nargs="+", default=["ins", "mekf"], choices=["ins", "mekf"])
    ap.add_argument("--seconds", type=float, default=180.0)
    ap.add_argument("--from-s", type=float, default=30.0)
    ap.add_argument("--processes", type=int, default=1)
    ap.add_argument("--hard-iron-error-ut", nargs="+", type=float, default=None,
                    help="the calibration's hard iron off by this much horizontally (body x-y), µT; one run each")
    ap.add_argument("--error-direction-deg", type=float, default=30.0,
                    help="direction of that error from the body x axis, degrees")
    ap.add_argument("--soft-iron-error", type=float, default=0.0,
                    help="the calibration's x-axis scale off by this fraction (with each hard-iron error)")
    ap.add_argument("--good-sigma-deg", type=float, default=5.0,
                    help="the daemon's [outputs] heading_good_sigma_deg")
    ap.add_argument("--no-field-circle", action="store_true",
                    help="without the calibration's circle check (estimator/field_circle.py): the filters before it")
    ap.add_argument("--no-iron-correction", action="store_true",
                    help="mekf: the circle check widens σ only, no learned hard iron (field_circle_correction.py)")
    ap.add_argument("--iron-step", action="store_true",
                    help="calibrated vehicles whose hard iron moves half-way (bench/vehicle_accuracy IRON_STEP_UT)")
    args = ap.parse_args(argv)
    # the simulated sensors' and estimators' warnings would bury the table; here, in main, not in one_run:
    # the pool's workers inherit it, and a test that calls one_run keeps its logging
    logging.disable(logging.WARNING)
    errors = [None]
    if args.hard_iron_error_ut is not None or args.soft_iron_error or args.iron_step:
        errors = [(e, math.radians(args.error_direction_deg), args.soft_iron_error)
                  for e in (args.hard_iron_error_ut or [0.0])]
    jobs = [Job(sc, seed, args.seconds, args.from_s, e, w, math.radians(args.good_sigma_deg),
                not args.no_field_circle, not args.no_iron_correction, args.iron_step)
            for w in errors for e in args.estimators for sc in args.scenarios for seed in args.seeds]
    print(f"without GNSS, {args.seconds:.0f} s, from {args.from_s:.0f} s: RMS roll/pitch/heading (°), "
          "σ median r/p/y (°), beyond 3σ r/p/h (%)" + ("" if errors == [None] else
                                                      "; % of samples MAGNETOMETER, % 'heading good', % off-centre"))
    with Pool(args.processes) as pool:
        for sc, seed, e, rms, med, beyond, wrong, mag_pct, good_pct, off_pct, after, step, moved in pool.imap(
                one_run, jobs):
            head = "" if wrong is None else f"Δb {wrong[0]:4.1f} µT soft {wrong[2]:+.2f}  "
            tail = "" if wrong is None else (f"   mag {mag_pct:5.1f} good {good_pct:5.1f} off-centre {off_pct:5.1f} "
                                             f"(from {after[1]:5.1f} s: hdg beyond {after[0]:5.1f}; from +60 s: hdg RMS "
                                             f"{after[2]:5.2f} beyond {after[3]:5.1f}); "
                                             f"corrected {moved[0]:5.1f} restarts {moved[1]}")
            if step is not None:
                tail += (f"; from step + 120 s: hdg RMS {step[0]:5.2f} σ med {step[1]:5.2f} beyond {step[2]:5.1f}; "
                         f"largest 0.1 s change {step[3]:4.2f}")
            print(f"{head}{e:5s} {sc:6s} seed {seed:3d}  RMS {rms[0]:5.2f} {rms[1]:5.2f} {rms[2]:5.2f}   σ "
                  f"{med[0]:5.2f} {med[1]:5.2f} {med[2]:5.2f}   beyond {beyond[0]:5.1f} {beyond[1]:5.1f} "
                  f"{beyond[2]:5.1f}{tail}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
