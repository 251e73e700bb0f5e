"""The heading checks at a start or restart of `ins` on a *calibrated* vehicle (the calibration exact, stating
0.5°), anywhere in its scenario — in a turn, heeled, banked — at a high dip: does the monitor reject the good
magnetometer, when, and what does the heading cost? Per run: the first rejection (s after the start, "-" for
none), the rejections and yaw resets (`Ins.heading_report`), the true-heading RMS over the first 30 s and after,
the share of heading errors beyond 3σ after 30 s and (last column, `h>3σ e`; with `--tilt` the tilt's, `t>3σ e`)
over the first 30 s. The gate's share of the filter's own attitude error (docs/gnss.md
"gate37") is what this was built to weigh; it also measures a start in a hard turn, which levelled the turn's
lean far beyond the stated tilt σ until the start levelled on the rotation axis (docs/estimator.md "turn37").

    python bench/restart_gate.py --scenario boat --starts 20 60 150 --seeds 1 2 3 4
    python bench/restart_gate.py --scenario car --starts 75 97 --seeds 1 2 3 --seconds 60
    python bench/restart_gate.py --scenario plane --starts 16 90 --seeds 1 2 3 --seconds 60
    python bench/restart_gate.py --scenario car --starts 75 --sites fairbanks --seeds 5 --seconds 60 --trace-every 5

`--bank` adds the GNSS yaw bank's validity against the truth: when it first said valid, its largest true-yaw error
while valid and the share of its valid samples beyond its own 3σ (docs/estimator.md "bank39"). `--tilt` adds the tilt RMS before / after 30 s and the share of tilt errors beyond 3σ after (σ: the roll and pitch
1σ in quadrature). `--trace-every S` also prints, per run, what the start levelled on (`levelling_force`'s figures: the force along
the rate's axis less g, across it, the axis's allowed error, and the true tilt of the force and of the axis) and,
at the start, 0.1 s and every S seconds, the tilt and true-heading errors and their 1σ, the GNSS yaw bank's error (valid or not), the heading checks'
magnetometer–bank disagreement, low-passed velocity NIS, the magnetometer's low-passed innovation and its
failures in a row (docs/estimator.md "hold37").
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.vehicle_accuracy import estimates_in_arrival_order, simulate_vehicle, tilt_heading_errors_deg  # noqa: E402

SITES = {"tromso": "69.65,18.96", "fairbanks": "64.84,-147.72", "punta_arenas": "-53.16,-70.91",
         "hobart": "-42.88,147.33", "reykjavik": "64.15,-21.94"}
SETTLE_S = 30.0


def start_levelling(run, rate_sigma_rad_s: float) -> str:
    """The first sample's levelling figures against the truth (scipy): what `levelling_force` tests."""
    from scipy.spatial.transform import Rotation
    f, w = np.asarray(run.accel_m_s2[0], dtype=float), np.asarray(run.gyro_rad_s[0], dtype=float)
    wn = float(np.linalg.norm(w))
    along = float(np.dot(f, w / wn))
    across = float(np.linalg.norm(f - along * w / wn))
    qw, qx, qy, qz = run.truth_q_wxyz[0]
    up_b = Rotation.from_quat([qx, qy, qz, qw]).inv().apply([0.0, 0.0, -1.0])
    def tilt(v):
        return np.degrees(np.arccos(min(1.0, abs(float(np.dot(v, up_b))) / float(np.linalg.norm(v)))))
    return (f"#   start: |f| {np.linalg.norm(f):.3f} m/s², rate {np.degrees(wn):.2f} °/s, along − g "
            f"{abs(along) - 9.80665:+.3f} m/s², across {across:.3f} m/s², axis allowed off "
            f"{np.degrees(np.arctan2(3.0 * rate_sigma_rad_s, wn)):.1f}°; true tilt of f {tilt(f):.1f}°, of the axis "
            f"{tilt(w):.1f}°")


def one_run(scenario: str, site: str, seed: int, start_s: float, seconds: float, trace_every_s: float = 0.0,
            bank: bool = False) -> dict:
    from ahrsd.estimator.ins import Ins
    from scipy.spatial.transform import Rotation

    run = simulate_vehicle(scenario, seconds, seed, SITES.get(site, site), mag="calibrated", start_s=start_s)
    est = Ins(declination_rad=run.declination_rad, lever_arm_m=run.lever_arm_m,
              mag_calibration_sigma_rad=run.mag_calibration_sigma_rad)
    n = len(run.t_s)
    q, sigma, sigma_tilt = np.empty((n, 4)), np.empty(n), np.empty(n)
    first = None
    if trace_every_s > 0.0:
        print(start_levelling(run, est.params.init_gyro_bias_sigma_rad_s))
    next_trace_s = 0.0
    bank_first_valid, bank_worst, bank_beyond, bank_valid_n = None, 0.0, 0, 0
    true_yaw_all = Rotation.from_quat(np.asarray(run.truth_q_wxyz)[:, [1, 2, 3, 0]]).as_euler("ZYX")[:, 0] if bank else None
    for k, e in estimates_in_arrival_order(est, run, run.fixes):
        q[k], sigma[k] = e.q_wxyz, e.sigma_rpy_rad[2]
        if bank:
            b_yaw, b_var, b_valid = est._heading.gnss_yaw()
            if b_valid:
                err = abs(float((b_yaw - true_yaw_all[k] + np.pi) % (2 * np.pi) - np.pi))
                bank_first_valid = float(run.t_s[k] - start_s) if bank_first_valid is None else bank_first_valid
                bank_worst = max(bank_worst, err)
                bank_beyond += err > 3.0 * np.sqrt(b_var)
                bank_valid_n += 1
        sigma_tilt[k] = np.hypot(e.sigma_rpy_rad[0], e.sigma_rpy_rad[1])
        if trace_every_s > 0.0 and run.t_s[k] - start_s >= next_trace_s:
            next_trace_s = 0.1 if next_trace_s == 0.0 else max(trace_every_s, next_trace_s + trace_every_s - 0.1 * (next_trace_s == 0.1))
            qw, qx, qy, qz = run.truth_q_wxyz[k]
            true_yaw = Rotation.from_quat([qx, qy, qz, qw]).as_euler("ZYX")[0]
            tilt_k, hdg_k = tilt_heading_errors_deg(q[k:k + 1], run.truth_q_wxyz[k:k + 1], run.declination_rad)
            bank_yaw, bank_var, bank_valid = est._heading.gnss_yaw()
            mon = est._heading.monitor
            print(f"#   {run.t_s[k] - start_s:5.1f} s: tilt {tilt_k[0]:5.1f}° (roll/pitch 1σ "
                  f"{np.degrees(e.sigma_rpy_rad[0]):5.2f}/{np.degrees(e.sigma_rpy_rad[1]):5.2f}°), "
                  f"heading {hdg_k[0]:7.2f}° (1σ {np.degrees(sigma[k]):6.2f}°), bank "
                  f"{np.degrees((bank_yaw - true_yaw + np.pi) % (2 * np.pi) - np.pi):7.2f}° (1σ "
                  f"{np.degrees(np.sqrt(bank_var)):6.2f}°, {'valid' if bank_valid else 'not valid'}), "
                  f"disagreement {np.degrees(mon.disagreement_rad):7.1f}°, NIS {mon.lowpassed_velocity_nis:5.1f}, "
                  f"innovation {np.degrees(mon.lowpassed_innovation_rad):5.1f}°, failures {mon.failures}", flush=True)
        if first is None and est.heading_report().mag_rejections > 0:
            first = float(run.t_s[k] - start_s)
    tilt, hdg = tilt_heading_errors_deg(q, run.truth_q_wxyz, run.declination_rad)
    t = run.t_s - start_s
    early, late = t < SETTLE_S, t >= SETTLE_S
    rep = est.heading_report()
    return {"first": first, "rejections": rep.mag_rejections, "resets": rep.yaw_resets,
            "early": float(np.sqrt(np.mean(hdg[early] ** 2))), "late": float(np.sqrt(np.mean(hdg[late] ** 2))),
            "beyond": float(np.mean(np.abs(hdg[late]) > 3.0 * np.degrees(sigma[late]))),
            "tilt_early": float(np.sqrt(np.mean(tilt[early] ** 2))), "tilt_late": float(np.sqrt(np.mean(tilt[late] ** 2))),
            "tilt_beyond": float(np.mean(tilt[late] > 3.0 * np.degrees(sigma_tilt[late]))),
            "bank_first_valid": bank_first_valid, "bank_worst_deg": float(np.degrees(bank_worst)),
            "bank_beyond": bank_beyond / bank_valid_n if bank_valid_n else 0.0,
            "beyond_early": float(np.mean(np.abs(hdg[early]) > 3.0 * np.degrees(sigma[early]))),
            "tilt_beyond_early": float(np.mean(tilt[early] > 3.0 * np.degrees(sigma_tilt[early])))}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default="boat")
    ap.add_argument("--sites", nargs="+", default=["tromso", "fairbanks"],
                    help=f"names ({', '.join(SITES)}) or LAT,LON[,ALT_M[,YYYY-MM-DD]]")
    ap.add_argument("--starts", type=float, nargs="+", default=[20.0, 60.0, 150.0],
                    help="where in the scenario each run starts, s")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4])
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--trace-every", type=float, default=0.0, help="print a trace every S s of each run (0: none)")
    ap.add_argument("--bank", action="store_true",
                    help="also the GNSS yaw bank: when it first said valid (s after the start, '-' never), its largest "
                         "true-yaw error while valid (deg) and the share of its valid samples beyond its own 3σ")
    ap.add_argument("--tilt", action="store_true",
                    help="also the tilt RMS before / after 30 s (deg) and the share of tilt errors beyond 3 hypot(σ_roll, "
                         "σ_pitch) after")
    args = ap.parse_args(argv)
    logging.disable(logging.WARNING)     # ins's own warnings for each rejection and reset
    print(f"# {args.scenario}, calibrated (0.5° stated), {args.seconds:g} s from each start: first rejection (s "
          f"after the start), rejections, yaw resets, heading RMS before / after {SETTLE_S:g} s (deg), beyond 3σ after")
    print(f"{'site':>10} {'start':>6} {'seed':>4} {'first':>6} {'rej':>3} {'rst':>3} {'early':>7} {'late':>7} "
          f"{'>3σ':>6}" + (f" {'tilt e':>7} {'tilt l':>7} {'>3σ':>6}" if args.tilt else "")
          + (f" {'bank v':>6} {'worst':>7} {'>3σ':>6}" if args.bank else "")
          + f" {'h>3σ e':>6}" + (f" {'t>3σ e':>6}" if args.tilt else ""))
    rejected = 0
    for site in args.sites:
        for start in args.starts:
            for seed in args.seeds:
                r = one_run(args.scenario, site, seed, start, args.seconds, args.trace_every, args.bank)
                rejected += r["rejections"] > 0
                first = "-" if r["first"] is None else f"{r['first']:.1f}"
                print(f"{site:>10} {start:6.0f} {seed:4d} {first:>6} {r['rejections']:3d} {r['resets']:3d} "
                      f"{r['early']:7.2f} {r['late']:7.2f} {100 * r['beyond']:5.1f}%"
                      + (f" {r['tilt_early']:7.2f} {r['tilt_late']:7.2f} {100 * r['tilt_beyond']:5.1f}%" if args.tilt else "")
                      + (f" {'-' if r['bank_first_valid'] is None else format(r['bank_first_valid'], '.1f'):>6} "
                         f"{r['bank_worst_deg']:7.2f} {100 * r['bank_beyond']:5.1f}%" if args.bank else "")
                      + f" {100 * r['beyond_early']:5.1f}%" + (f" {100 * r['tilt_beyond_early']:5.1f}%" if args.tilt else ""),
                      flush=True)
    print(f"# runs with a rejection: {rejected} of {len(args.sites) * len(args.starts) * len(args.seeds)}")


if __name__ == "__main__":
    main()
