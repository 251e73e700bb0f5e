"""Per-seed error time series of `ins` against the simulator's truth, for diagnosing the honest-heading figures:
heading / tilt RMS from 180 s, σ median and share beyond 3σ from 30 s (every 8th sample), then per 30 s the tilt
RMS, mean roll and pitch error, heading RMS, median yaw σ, heading state and the accelerometer bias error
(estimate − the simulator's turn-on bias, m/s²). With `--case iron-step` also the heading / tilt RMS from 120 s
after the iron step (the issue's target); with `--step` the largest change of the published heading error within
0.1 s (vehicle_accuracy.honesty_figures, every sample) and, with `--case iron-step`, the heading / tilt RMS from
30 s to the step (the issue's other iron-step target). With `--late S` also the heading / tilt RMS, σ median and share
beyond 3σ from S s on (`--seconds 900 --late 600`: whether a long run's error grows in its last 300 s). With `--tilt-sigma` the roll and pitch apart: the mean pitch
error and the median published roll / pitch σ from 180 s, and the shares of roll / pitch errors beyond 3σ of their
published σ from 30 s (the columns of docs/figures.md's held-back tilt tables, lean28 and tilt29).

`--site` is a name ("held-out": 33.9° S with VehicleIron.held_out; "default": the site and iron tuned on) or any
place "LAT,LON[,ALT_M[,YYYY-MM-DD]]" (with the held-out iron); `--iron` puts another iron there ("unseen":
VehicleIron.unseen, drawn, never used for a choice).

    python bench/heading_timeline.py --scenario boat --case uncalibrated --seeds 12 13 15 16
    python bench/heading_timeline.py --seeds 15 --timeline --params \
        '{"yaw_align_to_gnss_yaw": false, "accel_bias_needs_heading": false}'     # the filter before heading5
    python bench/heading_timeline.py --site 69.65,18.96 --iron unseen --seeds 11 14 17 --step   # Tromsø, dip 78°
    python bench/heading_timeline.py --site=-1.29,36.82 --iron unseen --scenario car --seeds 31 --tilt-sigma
    python bench/heading_timeline.py --site=64.84,-147.72 --seeds 91 --seconds 900 --late 600   # the last 300 s
    python bench/heading_timeline.py --site=-22.91,-43.17 --seeds 11 --field-anomaly-ut 1.0 --consistency

`--field-anomaly-ut E`: the true Earth field is WMM's plus E µT towards east (a local anomaly or WMM's own error,
fixed to north) while the estimator keeps WMM's field: what the magnetometer floor claims to cover.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from multiprocessing import Pool
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.vehicle_accuracy import (HONESTY_IRONS, IRON_STEP_AT, SETTLE_S, estimates_in_arrival_order,  # noqa: E402
                                    euler_errors_deg, honesty_figures, honesty_site, honesty_site_arg,
                                    simulate_vehicle, tilt_heading_errors_deg)

EVERY = 8          # keep every 8th sample (25 Hz of the 200 SPS runs)
TURN_DEG_S = 5.0   # --consistency: the vehicle is turning while its true heading rate is above this


def figures_from(t_s, heading_err_deg, tilt_err_deg, sigma_yaw_deg, from_s: float) -> tuple:
    """`--late`: heading RMS, tilt RMS, σ median (°) and the share of heading errors beyond 3σ over the samples at
    or after `from_s`; NaN where no sample is."""
    w = t_s >= from_s
    if not w.any():
        return (float("nan"),) * 4
    return (float(np.sqrt(np.mean(heading_err_deg[w] ** 2))), float(np.sqrt(np.mean(tilt_err_deg[w] ** 2))),
            float(np.median(sigma_yaw_deg[w])), float(np.mean(np.abs(heading_err_deg[w]) > 3.0 * sigma_yaw_deg[w])))


def anomaly_ned_ut(east_ut: float):
    """`--field-anomaly-ut`: E µT towards east as a NED vector (at right angles to the horizontal field where the
    declination is small: the largest heading offset for its size); 0: None, the simulator's field untouched."""
    return None if east_ut == 0.0 else (0.0, float(east_ut), 0.0)


def one_run(job) -> tuple:
    from ahrsd.estimator.ins import Ins
    from ahrsd.simulation import SensorErrors

    scen, case, seed, site_label, seconds, params, iron_label, anomaly_ut, *late_s = job  # late_s: `--late`
    site, iron = honesty_site(site_label, iron_label)
    run = simulate_vehicle(scen, seconds, seed, site, mag=case, iron=iron,
                           field_anomaly_ned_ut=anomaly_ned_ut(anomaly_ut))
    est = Ins(declination_rad=run.declination_rad, lever_arm_m=run.lever_arm_m,
              mag_calibration_sigma_rad=run.mag_calibration_sigma_rad, **params)
    t = run.t_s
    keep = np.arange(0, len(t), EVERY)
    q = np.empty((len(keep), 4))
    sig = np.empty(len(keep))
    sig_rp = np.empty((len(keep), 2))   # published roll, pitch σ (rad)
    state = np.zeros(len(keep), dtype=np.int8)
    ba = np.empty((len(keep), 3))
    # every sample's published heading for the largest 0.1 s step (honesty_figures)
    published = {"q": np.empty((len(t), 4)), "sigma_yaw_rad": np.empty(len(t)), "flags": np.zeros(len(t), np.int64)}
    j, arm_wrong_at_s = 0, None
    for k, e in estimates_in_arrival_order(est, run, run.fixes):
        if arm_wrong_at_s is None and k % EVERY == 0:       # the lever-arm check's latch (estimator/lever_arm_fit.py)
            fit = est.lever_arm_fit()
            arm_wrong_at_s = float(t[k]) if fit is not None and fit.arm_wrong else None
        published["q"][k], published["sigma_yaw_rad"][k] = e.q_wxyz, e.sigma_rpy_rad[2]
        published["flags"][k] = int(e.flags)
        if k % EVERY == 0:
            q[j], sig[j], state[j], ba[j] = e.q_wxyz, e.sigma_rpy_rad[2], int(e.heading_state), est.accel_bias_m_s2
            sig_rp[j] = e.sigma_rpy_rad[:2]
            j += 1
    tk = t[keep]
    tilt, hdg = tilt_heading_errors_deg(q, run.truth_q_wxyz[keep], run.declination_rad)
    rp = euler_errors_deg(q, run.truth_q_wxyz[keep])
    ba_err = ba - SensorErrors.adis16405(seed).accel_bias_m_s2
    late, honest = tk >= 180.0, tk >= 30.0
    after = tk >= IRON_STEP_AT * seconds + 120.0      # the iron-step case: from 120 s after the step
    before = (tk >= SETTLE_S) & (tk < IRON_STEP_AT * seconds)
    summary = (float(np.sqrt(np.mean(hdg[late] ** 2))), float(np.sqrt(np.mean(tilt[late] ** 2))),
               float(np.degrees(np.median(sig[honest]))),
               float(np.mean(np.abs(hdg[honest]) > 3.0 * np.degrees(sig[honest]))), est.yaw_resets,
               float(np.sqrt(np.mean(hdg[after] ** 2))), float(np.sqrt(np.mean(tilt[after] ** 2))),
               honesty_figures(run, published, SETTLE_S)["max_step_0_1s"],
               float(np.sqrt(np.mean(hdg[before] ** 2))), float(np.sqrt(np.mean(tilt[before] ** 2))))
    # heading error / published σ from 30 s by turn phase (truth heading rate above TURN_DEG_S, within 30 s after
    # one, later): (sum of squares, samples, samples beyond 3σ) per phase, pooled over seeds by --consistency
    z = hdg / np.degrees(sig)
    from scipy.spatial.transform import Rotation

    truth_euler_deg = Rotation.from_quat(run.truth_q_wxyz[keep][:, [1, 2, 3, 0]]).as_euler("ZYX", degrees=True)
    yaw_truth = np.unwrap(truth_euler_deg[:, 0] * np.pi / 180.0)
    turning = np.abs(np.degrees(np.gradient(yaw_truth, tk))) > TURN_DEG_S
    last_turn = np.maximum.accumulate(np.where(turning, tk, -np.inf))
    phases = {"turning": turning, "0-30 s after a turn": ~turning & (tk - last_turn < 30.0),
              "later": ~turning & (tk - last_turn >= 30.0)}
    consistency = {name: (float(np.sum(z[w & honest] ** 2)), int(np.sum(w & honest)),
                          int(np.sum(np.abs(z[w & honest]) > 3.0))) for name, w in phases.items()}
    # roll and pitch apart (ZYX: a yaw offset such as the declination leaves them unchanged): pitch mean and σ
    # medians from 180 s, shares beyond 3σ of each one's published σ from 30 s
    sig_rp_deg = np.degrees(sig_rp)
    tilt_sigma = {"pitch_mean": float(rp[late, 1].mean()),
                  "roll_beyond": float(np.mean(np.abs(rp[honest, 2]) > 3.0 * sig_rp_deg[honest, 0])),
                  "pitch_beyond": float(np.mean(np.abs(rp[honest, 1]) > 3.0 * sig_rp_deg[honest, 1])),
                  "roll_sigma": float(np.median(sig_rp_deg[late, 0])),
                  "pitch_sigma": float(np.median(sig_rp_deg[late, 1]))}
    rows = []
    for t0 in range(0, int(tk[-1]), 30):
        w = (tk >= t0) & (tk < t0 + 30)
        rows.append((t0, float(np.sqrt(np.mean(tilt[w] ** 2))), float(rp[w, 2].mean()), float(rp[w, 1].mean()),
                     float(np.sqrt(np.mean(hdg[w] ** 2))), float(np.degrees(np.median(sig[w]))),
                     int(np.bincount(state[w]).argmax()), ba_err[w].mean(axis=0)))
    fit = est.lever_arm_fit()
    arm = ("" if arm_wrong_at_s is None else f"  arm found wrong at {arm_wrong_at_s:.1f} s") + (
        f"  arm adopted, in use {','.join(f'{v:+.1f}' for v in np.add(run.lever_arm_m, fit.adopted_m))} m"
        if fit is not None and fit.arm_adopted else "")
    late = figures_from(tk, hdg, tilt, np.degrees(sig), late_s[0]) if late_s else None
    return job, summary, rows, (consistency, arm, late), tilt_sigma


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="boat")
    ap.add_argument("--case", default="uncalibrated", choices=["uncalibrated", "calibrated", "iron-step"])
    ap.add_argument("--site", type=honesty_site_arg, default="held-out",
                    help='"held-out", "default" or a place "LAT,LON[,ALT_M[,YYYY-MM-DD]]" (default held-out)')
    ap.add_argument("--iron", choices=HONESTY_IRONS, default=None,
                    help="the vehicle iron instead of the site's own (a place's own: held-out)")
    ap.add_argument("--step", action="store_true",
                    help="also print the largest change of the published heading error within 0.1 s (from 30 s) "
                         "and, with --case iron-step, the heading / tilt RMS from 30 s to the step")
    ap.add_argument("--seeds", type=int, nargs="+", default=[12, 13, 15, 16])
    ap.add_argument("--seconds", type=float, default=600.0)
    ap.add_argument("--params", default="{}", help="InsParams overrides as JSON")
    ap.add_argument("--timeline", action="store_true", help="also print the per-30 s rows")
    ap.add_argument("--late", type=float, default=None, metavar="S",
                    help="also print the heading / tilt RMS, σ median and share beyond 3σ from S s on")
    ap.add_argument("--field-anomaly-ut", type=float, default=0.0, metavar="E",
                    help="the true field = WMM's + E µT towards east; the estimator keeps WMM's (default 0: none)")
    ap.add_argument("--processes", type=int, default=2)
    ap.add_argument("--consistency", action="store_true",
                    help="also print, pooled over the seeds, the RMS of heading error / σ and the share beyond 3σ "
                         "while turning, within 30 s after a turn and later (from 30 s)")
    ap.add_argument("--tilt-sigma", action="store_true",
                    help="also print the pitch mean error and roll / pitch σ medians from 180 s and the roll / pitch "
                         "shares beyond 3σ from 30 s")
    args = ap.parse_args(argv)
    if args.late is not None and not 0.0 <= args.late < args.seconds:
        ap.error(f"--late {args.late:g} s is not within the run (0 to --seconds {args.seconds:g} s)")
    # the simulated sensors' and estimators' warnings would bury the table; here, in main, not in one_run:
    # the pool's workers inherit it, and a test that calls one_run keeps its logging
    logging.disable(logging.WARNING)
    params = json.loads(args.params)
    jobs = [(args.scenario, args.case, s, args.site, args.seconds, params, args.iron, args.field_anomaly_ut,
             *(() if args.late is None else (args.late,))) for s in args.seeds]
    iron = f", iron {args.iron}" if args.iron else ""
    iron += f", field anomaly {args.field_anomaly_ut:g} µT east" if args.field_anomaly_ut else ""
    print(f"ins {params or 'defaults'}, {args.scenario} {args.case}, site {args.site}{iron}, {args.seconds:.0f} s "
          f"(every {EVERY}th sample): heading / tilt RMS from 180 s, σ median and beyond 3σ from 30 s", flush=True)
    with Pool(args.processes) as pool:
        pooled = {}
        for job, (hdg, tilt, sig, beyond, resets, hdg_after, tilt_after, step, hdg_before, tilt_before), rows, \
                (consistency, arm, late), tilt_sigma in pool.imap(one_run, jobs):
            for name, (ss, n, out) in consistency.items():
                p_ss, p_n, p_out = pooled.get(name, (0.0, 0, 0))
                pooled[name] = (p_ss + ss, p_n + n, p_out + out)
            after = (f"  from 120 s after the step: heading {hdg_after:5.2f}°  tilt {tilt_after:5.2f}°"
                     if args.case == "iron-step" else "")
            step_text = f"  largest 0.1 s step {step:4.2f}°" if args.step else ""
            if args.step and args.case == "iron-step":
                step_text += f"  before the step: heading {hdg_before:5.2f}°  tilt {tilt_before:5.2f}°"
            print(f"seed {job[2]:3d}: heading {hdg:5.2f}°  tilt {tilt:5.3f}°  σ median {sig:5.2f}°  "
                  f"beyond 3σ {beyond:6.2%}  yaw resets {resets}{after}{step_text}{arm}", flush=True)
            if late is not None:
                print(f"          from {args.late:.0f} s: heading {late[0]:5.2f}°  tilt {late[1]:5.3f}°  σ median "
                      f"{late[2]:5.2f}°  beyond 3σ {late[3]:6.2%}", flush=True)
            if args.tilt_sigma:
                ts = tilt_sigma
                print(f"          pitch mean {ts['pitch_mean']:+6.3f}°  beyond 3σ pitch {ts['pitch_beyond']:6.2%} "
                      f"roll {ts['roll_beyond']:6.2%}  σ median pitch {ts['pitch_sigma']:5.3f}° "
                      f"roll {ts['roll_sigma']:5.3f}°", flush=True)
            if args.timeline:
                print("     t  tilt  roll err  pitch err  heading  σ yaw  state  accel bias error x y z (m/s²)")
                for t0, tl, re, pe, hd, sg, st, b in rows:
                    print(f"  {t0:4d}  {tl:4.2f}  {re:8.2f}  {pe:9.2f}  {hd:7.2f}  {sg:5.2f}  {st:5d}  "
                          f"{b[0]:+.3f} {b[1]:+.3f} {b[2]:+.3f}")
    if args.consistency:
        print(f"pooled over seeds {' '.join(map(str, args.seeds))}, from 30 s (Gaussian: RMS 1, 0.27 % beyond 3σ):")
        for name, (ss, n, out) in pooled.items():
            if n:
                print(f"  {name:20s} share {n / sum(v[1] for v in pooled.values()):4.0%}  RMS of error/σ "
                      f"{np.sqrt(ss / n):4.2f}  beyond 3σ {out / n:6.2%}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
