"""The heading checks at a start or restart of `ins` on a *calibrated* vehicle (the calibration exact, stating
0.5°), anywhere in its scenario — in a turn, heeled, banked — at a high dip: does the monitor reject the good
magnetometer, when, and what does the heading cost? Per run: the first rejection (s after the start, "-" for
none), the rejections and yaw resets (`Ins.heading_report`), the true-heading RMS over the first 30 s and after,
the share of heading errors beyond 3σ after 30 s. The gate's share of the filter's own attitude error (docs/gnss.md
"gate37") is what this was built to weigh; it also measures a start in a hard turn, which levelled the turn's
lean far beyond the stated tilt σ until the start levelled on the rotation axis (docs/estimator.md "turn37").

    python bench/restart_gate.py --scenario boat --starts 20 60 150 --seeds 1 2 3 4
    python bench/restart_gate.py --scenario car --starts 75 97 --seeds 1 2 3 --seconds 60
    python bench/restart_gate.py --scenario plane --starts 16 90 --seeds 1 2 3 --seconds 60
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

SITES = {"tromso": "69.65,18.96", "fairbanks": "64.84,-147.72"}
SETTLE_S = 30.0


def one_run(scenario: str, site: str, seed: int, start_s: float, seconds: float) -> dict:
    from ahrsd.estimator.ins import Ins

    run = simulate_vehicle(scenario, seconds, seed, SITES.get(site, site), mag="calibrated", start_s=start_s)
    est = Ins(declination_rad=run.declination_rad, lever_arm_m=run.lever_arm_m,
              mag_calibration_sigma_rad=run.mag_calibration_sigma_rad)
    n = len(run.t_s)
    q, sigma = np.empty((n, 4)), np.empty(n)
    first = None
    for k, e in estimates_in_arrival_order(est, run, run.fixes):
        q[k], sigma[k] = e.q_wxyz, e.sigma_rpy_rad[2]
        if first is None and est.heading_report().mag_rejections > 0:
            first = float(run.t_s[k] - start_s)
    _, hdg = tilt_heading_errors_deg(q, run.truth_q_wxyz, run.declination_rad)
    t = run.t_s - start_s
    early, late = t < SETTLE_S, t >= SETTLE_S
    rep = est.heading_report()
    return {"first": first, "rejections": rep.mag_rejections, "resets": rep.yaw_resets,
            "early": float(np.sqrt(np.mean(hdg[early] ** 2))), "late": float(np.sqrt(np.mean(hdg[late] ** 2))),
            "beyond": float(np.mean(np.abs(hdg[late]) > 3.0 * np.degrees(sigma[late])))}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default="boat")
    ap.add_argument("--sites", nargs="+", default=["tromso", "fairbanks"],
                    help=f"names ({', '.join(SITES)}) or LAT,LON[,ALT_M[,YYYY-MM-DD]]")
    ap.add_argument("--starts", type=float, nargs="+", default=[20.0, 60.0, 150.0],
                    help="where in the scenario each run starts, s")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4])
    ap.add_argument("--seconds", type=float, default=30.0)
    args = ap.parse_args(argv)
    logging.disable(logging.WARNING)     # ins's own warnings for each rejection and reset
    print(f"# {args.scenario}, calibrated (0.5° stated), {args.seconds:g} s from each start: first rejection (s "
          f"after the start), rejections, yaw resets, heading RMS before / after {SETTLE_S:g} s (deg), beyond 3σ after")
    print(f"{'site':>10} {'start':>6} {'seed':>4} {'first':>6} {'rej':>3} {'rst':>3} {'early':>7} {'late':>7} "
          f"{'>3σ':>6}")
    rejected = 0
    for site in args.sites:
        for start in args.starts:
            for seed in args.seeds:
                r = one_run(args.scenario, site, seed, start, args.seconds)
                rejected += r["rejections"] > 0
                first = "-" if r["first"] is None else f"{r['first']:.1f}"
                print(f"{site:>10} {start:6.0f} {seed:4d} {first:>6} {r['rejections']:3d} {r['resets']:3d} "
                      f"{r['early']:7.2f} {r['late']:7.2f} {100 * r['beyond']:5.1f}%", flush=True)
    print(f"# runs with a rejection: {rejected} of {len(args.sites) * len(args.starts) * len(args.seeds)}")


if __name__ == "__main__":
    main()
