"""Where ins's tilt error on a vehicle without magnetometer calibration comes from, split with the simulator's
truth (docs/estimator.md "The uncalibrated boat's tilt: the x and y gyros' misalignment towards z").

    .venv/bin/python bench/tilt_split.py [--scenario boat] [--seeds 12 13 15 16 11 14 17] [--processes 1]
    .venv/bin/python bench/tilt_split.py --scenario car --site=-1.29,36.82 --seeds 31 \
        --rows defaults "sensor lean = 0" "gyro m prior 0.1°"          # the uncalibrated car's pitch at Nairobi

Each seed is run (held-out site and iron unless `--site` / `--iron` say otherwise, 600 s, GNSS 5 Hz, every 8th
sample kept) once per row:
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
  calibrated        the same sensor with a calibrated magnetometer (the simulator's exact iron removed);
  sensor lean = 0   the accelerometer z axis's lean towards x and y (m_zx, m_zy) removed from the sensor;
  gyro m prior 0.1° the filter's gyro misalignment prior at the simulated sensor's 0.1° (it is 0.2°);
  IMU perfect       the gyro and accelerometer without any error (SensorErrors.ideal's), the magnetometer and the
                    receiver as simulated: what the receiver's errors alone leave;
  IMU perfect, velocity noise 0
                    and the receiver's velocity without its white noise (its reported accuracy kept);
  IMU perfect, horizontal velocity noise 0
                    the same, the noise taken out of the north and east velocity only (the down velocity keeps it).
Per seed and row: heading and tilt RMS from 180 s, the mean pitch and roll errors from 180 s, the forward
accelerometer-bias error expressed as a pitch ((b̂_x − b_x)/g, from 180 s: the pair cancels when it is −pitch),
the median published pitch σ, and the share of heading errors beyond 3σ from 30 s; then the mean pitch error over
30–90 s, and the pitch and roll the filter's priors alone choose for the common rotation of the sensor's axes that
a vehicle turning on level ground never observes (`unobserved_rotation_deg`, from the simulator's truth). With
`--trace`, per window of the run the mean pitch error and the filter's errors in the three elements of that
rotation (the forward bias as a pitch, the accelerometer's m_zx, the x gyro's m_xz).
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import sys
from multiprocessing import Pool
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.vehicle_accuracy import (GNSS_ERRORS, HONESTY_IRONS, euler_errors_deg, honesty_site, honesty_site_arg,  # noqa: E402
                                    simulate_vehicle, tilt_heading_errors_deg)

EVERY = 8
ROWS = ("defaults", "m_xz,m_yz truth", "accel bias truth", "sensor m = 0", "no m states", "neither", "calibrated",
        "sensor lean = 0", "gyro m prior 0.1°", "IMU perfect", "IMU perfect, velocity noise 0",
        "IMU perfect, horizontal velocity noise 0")
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


def perfect_imu(errors):
    """`errors` with the gyro's and the accelerometer's every error removed (SensorErrors.ideal's), the
    magnetometer's kept."""
    from ahrsd.simulation import SensorErrors

    ideal = SensorErrors.ideal()
    names = [n for n in vars(ideal) if n.startswith(("gyro_", "accel_"))]
    return errors.replace(**{n: getattr(ideal, n) for n in names})


def quiet_velocity_receiver():
    """The benches' receiver (vehicle_accuracy.GNSS_ERRORS) without the white noise on its velocity, reporting the
    same speed accuracy: its position errors are drawn as before."""
    from ahrsd.simulation import GnssErrors

    return GnssErrors(**{**GNSS_ERRORS, "velocity_m_s": 0.0, "s_acc_m_s": GNSS_ERRORS["velocity_m_s"]})


def with_down_velocity_of(quiet, noisy) -> list:
    """The fixes `quiet` (no velocity noise) with the down velocity of `noisy` (the same fixes with it)."""
    out = []
    for q, n in zip(quiet, noisy, strict=True):
        v = q.vel_ned_m_s.copy()
        v[2] = n.vel_ned_m_s[2]
        out.append(dataclasses.replace(q, vel_ned_m_s=v))
    return out


def unobserved_rotation_deg(errors, params) -> tuple[float, float]:
    """(pitch, roll) error, deg, that the filter's priors alone choose for a common rotation of the sensor's axes.

    A rotation ε of the body frame the filter believes in is, to every reading, the same as adding [ε×] to both
    the accelerometer's and the gyro's misalignment (f_meas = (I + M) f^b). About y that moves the x axes' m_xz by
    +ε and the z axes' m_zx by −ε; about x, m_yz by −ε and m_zy by +ε. Level, the accelerometer's m_xz is one error
    with its x bias (the filter's b_x stands for −g m_xz + b_x); the z gyro's m_zx, m_zy multiply roll and pitch
    rates a vehicle on level ground hardly has, so they hold nothing. What is left, the accelerometer's bias (as
    m_xz), its z axis's lean and the x / y gyros' m_xz, m_yz, nothing on a vehicle that turns about the vertical
    tells apart (docs/estimator.md "The uncalibrated car's pitch at Nairobi"): the filter ends at the ε that makes
    its estimates, truth + s ε, most likely under its priors, ε = −Σ w s t / Σ w (w = 1/σ², s = ±1). The lean
    counts while the filter carries it (`accel_axes_tilt_sigma_rad` > 0), the gyro's while
    `init_gyro_misalignment_sigma_rad` > 0. Independent of the filter's code: the simulator's errors and the priors'
    figures only."""
    ma, mg, b = errors.accel_misalignment_rad, errors.gyro_misalignment_rad, errors.accel_bias_m_s2
    w_b = (G_M_S2 / params["init_accel_bias_sigma_m_s2"]) ** 2
    w_a = params["accel_axes_tilt_sigma_rad"] ** -2 if params["accel_axes_tilt_sigma_rad"] > 0 else 0.0
    w_g = params["init_gyro_misalignment_sigma_rad"] ** -2 if params["init_gyro_misalignment_sigma_rad"] > 0 else 0.0
    out = []
    # (truth t, sign s, weight w) of each element: pitch (about y), then roll (about x)
    for terms in ([(ma[0, 2] - b[0] / G_M_S2, 1.0, w_b), (ma[2, 0], -1.0, w_a), (mg[0, 2], 1.0, w_g)],
                  [(ma[1, 2] - b[1] / G_M_S2, -1.0, w_b), (ma[2, 1], 1.0, w_a), (mg[1, 2], -1.0, w_g)]):
        out.append(math.degrees(-sum(w * s * t for t, s, w in terms) / sum(w for _, _, w in terms)))
    return out[0], out[1]


def _population(n: int) -> int:
    from ahrsd.estimator.ins import InsParams
    from ahrsd.simulation import SensorErrors

    p = InsParams()
    sensors = [SensorErrors.adis16405(seed) for seed in range(1, n + 1)]
    print(f"simulated ADIS16405 seeds 1–{n}: RMS of the pitch / roll error the priors choose along the unobserved "
          f"rotation (ins's accelerometer bias prior {p.init_accel_bias_sigma_m_s2} m/s², lean prior "
          f"{math.degrees(p.accel_axes_tilt_sigma_rad):.2f}°; its gyro prior "
          f"{math.degrees(p.init_gyro_misalignment_sigma_rad):.2f}°)")
    for gyro_deg in np.arange(0.04, 0.41, 0.02):
        cells = []
        for lean_rad in (p.accel_axes_tilt_sigma_rad, 0.0):
            priors = {"init_accel_bias_sigma_m_s2": p.init_accel_bias_sigma_m_s2, "accel_axes_tilt_sigma_rad": lean_rad,
                      "init_gyro_misalignment_sigma_rad": math.radians(gyro_deg)}
            e = np.array([unobserved_rotation_deg(s, priors) for s in sensors])
            cells.append("%.4f / %.4f°" % tuple(np.sqrt(np.mean(e ** 2, axis=0))))
        print(f"  gyro prior {gyro_deg:.2f}°  with the lean {cells[0]}  without {cells[1]}")
    return 0


def one_run(job) -> tuple:
    from ahrsd.core.sample import SampleFlags, make_sample
    from ahrsd.estimator import ins_core as core
    from ahrsd.estimator.ins import Ins
    from ahrsd.simulation import SensorErrors
    from ahrsd.simulation.errors import MISALIGN_SIGMA_RAD as SIM_MISALIGN_SIGMA_RAD

    scen, seed, row, seconds = job[:4]
    site, iron = honesty_site(*(job[4:6] if len(job) > 4 else ("held-out", None)))
    errors = SensorErrors.adis16405(seed)
    if row in ("sensor m = 0", "neither"):
        errors = errors.replace(gyro_misalignment_rad=np.zeros((3, 3)))
    if row == "sensor lean = 0":
        ma = errors.accel_misalignment_rad.copy()
        ma[2, :2] = 0.0
        errors = errors.replace(accel_misalignment_rad=ma)
    if row.startswith("IMU perfect"):
        errors = perfect_imu(errors)
    mag = "calibrated" if row == "calibrated" else "uncalibrated"
    run = simulate_vehicle(scen, seconds, seed, site, mag=mag, iron=iron, errors=errors)
    if row.endswith("velocity noise 0"):
        quiet = simulate_vehicle(scen, seconds, seed, site, mag=mag, iron=iron, errors=errors,
                                 gnss_errors=quiet_velocity_receiver()).fixes
        run.fixes[:] = quiet if row == "IMU perfect, velocity noise 0" else with_down_velocity_of(quiet, run.fixes)
    params = {"init_gyro_misalignment_sigma_rad": 0.0} if row in ("no m states", "neither") else {}
    if row == "gyro m prior 0.1°":
        params = {"init_gyro_misalignment_sigma_rad": SIM_MISALIGN_SIGMA_RAD}
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
    lean_gyro = np.empty((len(keep), 2))   # the filter's accelerometer m_zx and x gyro m_xz (rad)
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
            lean_gyro[j] = est._x["accel_z_lean_rad"][0], est.gyro_misalignment_rad[0, 2]
            j += 1
    tk = t[keep]
    tilt, hdg = tilt_heading_errors_deg(q, run.truth_q_wxyz[keep], run.declination_rad)
    rp = euler_errors_deg(q, run.truth_q_wxyz[keep])
    late, honest, early = tk >= 180.0, tk >= 30.0, (tk >= 30.0) & (tk < 90.0)
    p = est.params
    priors = {k: getattr(p, k) for k in ("init_accel_bias_sigma_m_s2", "accel_axes_tilt_sigma_rad",
                                         "init_gyro_misalignment_sigma_rad")}
    return job, (float(np.sqrt(np.mean(hdg[late] ** 2))), float(np.sqrt(np.mean(tilt[late] ** 2))),
                 float(rp[late, 1].mean()), float(rp[late, 2].mean()),
                 math.degrees(float(np.mean(bx[late]) - level_bias[0]) / G_M_S2),
                 float(np.degrees(np.median(sig[late, 1]))),
                 float(np.mean(np.abs(hdg[honest]) > 3.0 * np.degrees(sig[honest, 2]))),
                 float(rp[early, 1].mean()), *unobserved_rotation_deg(errors, priors),
                 _trace(tk, rp[:, 1], np.degrees((bx - level_bias[0]) / G_M_S2),
                        np.degrees(lean_gyro - [errors.accel_misalignment_rad[2, 0], m[0, 2]])))


TRACE_WINDOWS_S = (0.0, 10.0, 20.0, 40.0, 90.0, 180.0, 300.0, 450.0, 600.0)


def _trace(t_s, pitch_deg, bias_deg, lean_gyro_deg) -> list:
    """Per window of TRACE_WINDOWS_S: (start, end, mean pitch error, forward bias error as a pitch, the filter's
    accelerometer m_zx error, its x gyro m_xz error), deg; along the unobserved rotation ε the last three are
    −ε, −ε and +ε (unobserved_rotation_deg)."""
    rows = []
    for a, b in zip(TRACE_WINDOWS_S[:-1], TRACE_WINDOWS_S[1:]):
        w = (t_s >= a) & (t_s < b)
        if w.any():
            rows.append((a, b, float(pitch_deg[w].mean()), float(bias_deg[w].mean()),
                         *(float(v) for v in lean_gyro_deg[w].mean(axis=0))))
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="boat")
    ap.add_argument("--site", type=honesty_site_arg, default="held-out",
                    help='"held-out", "default" or a place "LAT,LON[,ALT_M[,YYYY-MM-DD]]" (with the held-out iron)')
    ap.add_argument("--iron", choices=HONESTY_IRONS, default=None, help="the vehicle iron instead of the site's own")
    ap.add_argument("--seeds", type=int, nargs="+", default=[12, 13, 15, 16, 11, 14, 17])
    ap.add_argument("--rows", nargs="+", default=list(ROWS), choices=ROWS)
    ap.add_argument("--seconds", type=float, default=600.0)
    ap.add_argument("--processes", type=int, default=1)
    ap.add_argument("--population", type=int, default=0, metavar="N",
                    help="instead of runs: over the simulated sensors of seeds 1..N, the RMS of the pitch / roll the "
                         "priors choose for the unobserved rotation, for gyro misalignment priors 0.04–0.40°, with "
                         "the accelerometer's lean in the set (a car, a plane) and without it (no forward "
                         "acceleration: a boat)")
    ap.add_argument("--trace", action="store_true",
                    help="also print, per window of the run, the mean pitch error and the filter's errors in the "
                         "forward bias (as a pitch), the accelerometer's m_zx and the x gyro's m_xz")
    args = ap.parse_args(argv)
    if args.population:
        return _population(args.population)
    # the simulated sensors' and estimators' warnings would bury the table; here, in main, not in one_run:
    # the pool's workers inherit it, and a test that calls one_run keeps its logging
    logging.disable(logging.WARNING)
    jobs = [(args.scenario, s, r, args.seconds, args.site, args.iron) for s in args.seeds for r in args.rows]
    print(f"ins, {args.scenario} (site {args.site}, iron {args.iron or 'its own'}, {args.seconds:.0f} s, every {EVERY}th sample): heading / "
          "tilt RMS from 180 s; from 180 s the mean pitch and roll errors, the forward accelerometer-bias error as a "
          "pitch ((b̂_x − b_x)/g) and the median pitch σ; heading beyond 3σ from 30 s; the mean pitch error over 30–90 s; "
          "the pitch / roll the priors choose for the unobserved rotation of the sensor's axes", flush=True)
    with Pool(args.processes) as pool:
        for job, out in pool.imap(one_run, jobs):
            hdg, tilt, pitch, roll, bias_deg, sig_pitch, beyond, pitch_early, prior_pitch, prior_roll, trace = out
            print(f"seed {job[1]:3d}  {job[2]:17s} heading {hdg:5.2f}°  tilt {tilt:5.3f}°  pitch {pitch:+6.3f}°  "
                  f"roll {roll:+6.3f}°  forward bias {bias_deg:+5.2f}°  pitch σ {sig_pitch:4.2f}°  "
                  f"beyond 3σ {beyond:6.2%}  pitch 30–90 s {pitch_early:+6.3f}°  "
                  f"priors' rotation pitch {prior_pitch:+6.3f}° roll {prior_roll:+6.3f}°", flush=True)
            for a, b, p, bias, lean, gyro in trace if args.trace else ():
                print(f"      {a:3.0f}–{b:3.0f} s  pitch {p:+6.3f}°  forward bias {bias:+6.3f}°  "
                      f"accelerometer m_zx error {lean:+6.3f}°  x gyro m_xz error {gyro:+6.3f}°", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
