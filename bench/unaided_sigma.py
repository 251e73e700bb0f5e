"""ins and mekf without GNSS on the simulated vehicles that speed up, brake and turn (boat, car, plane): roll,
pitch and heading RMS against the simulator's truth, the median published 1σ and the share of samples beyond 3σ,
from --from-s on (the magnetometer calibrated, the default site, 200 Hz: bench/vehicle_accuracy.simulate_vehicle).

    .venv/bin/python bench/unaided_sigma.py --scenarios boat car plane --seeds 12 13 15 16 11 14 17
"""

from __future__ import annotations

import argparse
import logging
import sys
from multiprocessing import Pool
from pathlib import Path

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


def one_run(job) -> tuple:
    from ahrsd.core.sample import SampleFlags, make_sample
    from ahrsd.estimator.ins import Ins
    from ahrsd.estimator.mekf import Mekf

    scenario, seed, seconds, from_s, estimator = job
    run = simulate_vehicle(scenario, seconds, seed, None)
    n = len(run.t_s)
    q = np.full((n, 4), np.nan)
    sig = np.full((n, 3), np.nan)
    if estimator == "ins":
        est = Ins(declination_rad=run.declination_rad, mag_calibration_sigma_rad=run.mag_calibration_sigma_rad)
        step = est.update
    else:
        est = Mekf()
        step = est.update
    for k in range(n):
        e = step(make_sample(run.t_s[k], run.gyro_rad_s[k], run.accel_m_s2[k], run.mag_ut[k],
                             flags=SampleFlags.NEW_DATA))
        q[k] = e.q_wxyz
        sig[k] = e.sigma_rpy_rad
    ok = (run.t_s >= from_s) & np.all(np.isfinite(q), axis=1)
    err = errors_rph(q[ok], run.truth_q_wxyz[ok], run.declination_rad)
    s = sig[ok]
    rms = np.degrees(np.sqrt(np.mean(err ** 2, axis=0)))
    beyond = 100.0 * np.mean(np.abs(err) > 3.0 * s, axis=0)
    return scenario, seed, estimator, rms, np.degrees(np.median(s, axis=0)), beyond


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", nargs="+", default=["boat", "car", "plane"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[12, 13, 15, 16])
    ap.add_argument("--estimators", nargs="+", default=["ins", "mekf"], choices=["ins", "mekf"])
    ap.add_argument("--seconds", type=float, default=180.0)
    ap.add_argument("--from-s", type=float, default=30.0)
    ap.add_argument("--processes", type=int, default=1)
    args = ap.parse_args(argv)
    # the simulated sensors' and estimators' warnings would bury the table; here, in main, not in one_run:
    # the pool's workers inherit it, and a test that calls one_run keeps its logging
    logging.disable(logging.WARNING)
    jobs = [(sc, seed, args.seconds, args.from_s, e) for e in args.estimators for sc in args.scenarios
            for seed in args.seeds]
    print(f"without GNSS, {args.seconds:.0f} s, from {args.from_s:.0f} s: RMS roll/pitch/heading (°), "
          "σ median r/p/y (°), beyond 3σ r/p/h (%)")
    with Pool(args.processes) as pool:
        for sc, seed, e, rms, med, beyond in pool.imap(one_run, jobs):
            print(f"{e:5s} {sc:6s} seed {seed:3d}  RMS {rms[0]:5.2f} {rms[1]:5.2f} {rms[2]:5.2f}   σ {med[0]:5.2f} "
                  f"{med[1]:5.2f} {med[2]:5.2f}   beyond {beyond[0]:5.1f} {beyond[1]:5.1f} {beyond[2]:5.1f}",
                  flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
