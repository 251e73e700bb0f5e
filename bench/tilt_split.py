"""Where ins's tilt error on a vehicle without magnetometer calibration comes from, split with the simulator's
truth (docs/estimator.md "The uncalibrated boat's tilt: the x and y gyros' misalignment towards z").

    .venv/bin/python bench/tilt_split.py [--scenario boat] [--seeds 12 13 15 16 11 14 17] [--processes 1]

Each seed is run (held-out site and iron, 600 s, GNSS 5 Hz, every 8th sample kept) once per row:
  defaults          ins as it is, the sensor as simulated (SensorErrors.adis16405(seed)), no calibration;
  m_xz,m_yz truth   the x and y gyros' misalignment towards z (what they pick up of the turn rate) written into
                    the filter at the simulator's value after every fix, its covariance rows cleared (an oracle:
                    the filter's private state, for diagnosis only);
  accel bias truth  the horizontal accelerometer bias likewise, at what the sensor adds when level: the turn-on
                    bias + (scale, misalignment) × gravity;
  sensor m = 0      the sensor's gyro misalignment removed, the filter unchanged;
  no m states       the filter without its misalignment states (init_gyro_misalignment_sigma_rad 0), the sensor
                    as simulated;
  neither           both: no gyro misalignment in the sensor, no misalignment states in the filter;
  calibrated        the same sensor with a calibrated magnetometer (the simulator's exact iron removed).
Per seed and row: heading and tilt RMS from 180 s, the mean pitch and roll errors from 180 s, the forward
accelerometer-bias error expressed as a pitch ((b̂_x − b_x)/g, from 180 s: the pair cancels when it is −pitch),
the median published pitch σ, and the share of heading errors beyond 3σ from 30 s.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
from multiprocessing import Pool
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.vehicle_accuracy import HONESTY_SITES, simulate_vehicle, tilt_heading_errors_deg  # noqa: E402

EVERY = 8
ROWS = ("defaults", "m_xz,m_yz truth", "accel bias truth", "sensor m = 0", "no m states", "neither", "calibrated")
G_M_S2 = 9.80665


def _hold(est, index: int, value: float, var: float) -> None:
    """Oracle: error-state component `index` set to `value` in the filter's state, its covariance decoupled."""
    from ahrsd.estimator import ins_core as core

    if index < core.E_MG:
        est._x["accel_bias_m_s2"][index - core.E_BA] = value
    else:
        est._x["gyro_misalignment_rad"][index - core.E_MG] = value
    est._P[index, :] = 0.0
    est._P[:, index] = 0.0
    est._P[index, index] = var


def one_run(job) -> tuple:
    from scipy.spatial.transform import Rotation

    from ahrsd.core.sample import SampleFlags, make_sample
    from ahrsd.estimator import ins_core as core
    from ahrsd.estimator.ins import Ins
    from ahrsd.simulation import SensorErrors

    scen, seed, row, seconds = job
    site, iron = HONESTY_SITES["held-out"]
    errors = SensorErrors.adis16405(seed)
    if row in ("sensor m = 0", "neither"):
        errors = errors.replace(gyro_misalignment_rad=np.zeros((3, 3)))
    mag = "calibrated" if row == "calibrated" else "uncalibrated"
    run = simulate_vehicle(scen, seconds, seed, site, mag=mag, iron=iron, errors=errors)
    params = {"init_gyro_misalignment_sigma_rad": 0.0} if row in ("no m states", "neither") else {}
    est = Ins(declination_rad=run.declination_rad, lever_arm_m=run.lever_arm_m,
              mag_calibration_sigma_rad=run.mag_calibration_sigma_rad, **params)
    m = errors.gyro_misalignment_rad
    # what the accelerometer adds to a level vehicle's specific force (0, 0, −g): the filter's bias stands for it
    level_bias = errors.accel_bias_m_s2 + (errors.accel_matrix - np.eye(3)) @ np.array([0.0, 0.0, -G_M_S2])
    holds = {"m_xz,m_yz truth": [(core.E_MG + 1, m[0, 2], 1e-12), (core.E_MG + 3, m[1, 2], 1e-12)],
             "accel bias truth": [(core.E_BA, level_bias[0], 1e-8), (core.E_BA + 1, level_bias[1], 1e-8)]}.get(row, [])
    t, g, a, mg = run.t_s, run.gyro_rad_s, run.accel_m_s2, run.mag_ut
    keep = np.arange(0, len(t), EVERY)
    q = np.empty((len(keep), 4))
    sig = np.empty((len(keep), 3))
    bx = np.empty(len(keep))
    fi = j = 0
    for k in range(len(t)):
        while fi < len(run.fixes) and run.fixes[fi].extra["t_rx_s"] <= t[k]:
            est.update_gnss(run.fixes[fi])
            fi += 1
            if est._initialised:
                for index, value, var in holds:
                    _hold(est, index, value, var)
        # step, and the estimate built at the samples read only (estimator/estimate_view.py: building none
        # changes none)
        view = est.step(make_sample(t[k], g[k], a[k], mg[k], flags=SampleFlags.NEW_DATA))
        if k % EVERY == 0:
            e = view.snapshot()
            q[j], sig[j], bx[j] = e.q_wxyz, e.sigma_rpy_rad, est.accel_bias_m_s2[0]
            j += 1
    tk = t[keep]
    tilt, hdg = tilt_heading_errors_deg(q, run.truth_q_wxyz[keep], run.declination_rad)
    eul = lambda qq: Rotation.from_quat(qq[:, [1, 2, 3, 0]]).as_euler("ZYX", degrees=True)  # noqa: E731
    rp = (eul(q) - eul(run.truth_q_wxyz[keep]) + 180.0) % 360.0 - 180.0
    late, honest = tk >= 180.0, tk >= 30.0
    return job, (float(np.sqrt(np.mean(hdg[late] ** 2))), float(np.sqrt(np.mean(tilt[late] ** 2))),
                 float(rp[late, 1].mean()), float(rp[late, 2].mean()),
                 math.degrees(float(np.mean(bx[late]) - level_bias[0]) / G_M_S2),
                 float(np.degrees(np.median(sig[late, 1]))),
                 float(np.mean(np.abs(hdg[honest]) > 3.0 * np.degrees(sig[honest, 2]))))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="boat")
    ap.add_argument("--seeds", type=int, nargs="+", default=[12, 13, 15, 16, 11, 14, 17])
    ap.add_argument("--rows", nargs="+", default=list(ROWS), choices=ROWS)
    ap.add_argument("--seconds", type=float, default=600.0)
    ap.add_argument("--processes", type=int, default=1)
    args = ap.parse_args(argv)
    # the simulated sensors' and estimators' warnings would bury the table; here, in main, not in one_run:
    # the pool's workers inherit it, and a test that calls one_run keeps its logging
    logging.disable(logging.WARNING)
    jobs = [(args.scenario, s, r, args.seconds) for s in args.seeds for r in args.rows]
    print(f"ins, {args.scenario} (held-out site and iron, {args.seconds:.0f} s, every {EVERY}th sample): heading / "
          "tilt RMS from 180 s; from 180 s the mean pitch and roll errors, the forward accelerometer-bias error as a "
          "pitch ((b̂_x − b_x)/g) and the median pitch σ; heading beyond 3σ from 30 s", flush=True)
    with Pool(args.processes) as pool:
        for (_, seed, row, _), (hdg, tilt, pitch, roll, bias_deg, sig_pitch, beyond) in pool.imap(one_run, jobs):
            print(f"seed {seed:3d}  {row:17s} heading {hdg:5.2f}°  tilt {tilt:5.2f}°  pitch {pitch:+5.2f}°  "
                  f"roll {roll:+5.2f}°  forward bias {bias_deg:+5.2f}°  pitch σ {sig_pitch:4.2f}°  "
                  f"beyond 3σ {beyond:6.2%}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
