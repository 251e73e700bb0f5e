"""The honest-heading figures of bench/vehicle_accuracy.py section (d) for `ins` alone, over many seeds, in
parallel processes: heading / tilt RMS, σ median, share beyond 3σ and the largest 0.1 s step per run, and their
spread. Used to choose the heading parameters on held-out-site seeds other than the reported seed 11.
`--site` / `--iron` as bench/heading_timeline.py's: a name or any place "LAT,LON[,ALT_M[,YYYY-MM-DD]]", another iron.

    python bench/honesty_spread.py --site held-out --seeds 12 13 14 15 16 17 --scenarios boat
    python bench/honesty_spread.py --site 69.65,18.96 --iron unseen --seeds 11 14 17 --scenarios boat   # Tromsø
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from multiprocessing import Pool
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.vehicle_accuracy import (HONESTY_IRONS, IRON_STEP_AT, honesty_figures, honesty_site,  # noqa: E402
                                    honesty_site_arg, run_ins_detailed, simulate_vehicle)


def one_run(job) -> tuple:
    scen, case, seed, site_label, seconds, params, iron_label = job
    site, iron = honesty_site(site_label, iron_label)
    run = simulate_vehicle(scen, seconds, seed, site, mag=case, iron=iron)
    out = run_ins_detailed(run, **params)
    if case == "uncalibrated":
        return job, honesty_figures(run, out, 180.0), None
    t_step = IRON_STEP_AT * seconds
    return job, honesty_figures(run, out, 30.0, t_step), honesty_figures(run, out, t_step + 120.0)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--site", type=honesty_site_arg, default="held-out",
                    help='"held-out", "default" or a place "LAT,LON[,ALT_M[,YYYY-MM-DD]]" (default held-out)')
    ap.add_argument("--iron", choices=HONESTY_IRONS, default=None,
                    help="the vehicle iron instead of the site's own (a place's own: held-out)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[12, 13, 14, 15, 16, 17])
    ap.add_argument("--scenarios", nargs="+", default=["boat", "car", "plane"])
    ap.add_argument("--cases", nargs="+", default=["uncalibrated", "iron-step"], choices=["uncalibrated", "iron-step"])
    ap.add_argument("--seconds", type=float, default=600.0)
    ap.add_argument("--params", default="{}", help="InsParams overrides as JSON, e.g. '{\"iron_soft_prior_sigma\": 0}'")
    ap.add_argument("--processes", type=int, default=2)
    args = ap.parse_args(argv)
    # the simulated sensors' and estimators' warnings would bury the table; here, in main, not in one_run:
    # the pool's workers inherit it, and a test that calls one_run keeps its logging
    logging.disable(logging.WARNING)
    params = json.loads(args.params)
    jobs = [(s, c, seed, args.site, args.seconds, params, args.iron)
            for s in args.scenarios for c in args.cases for seed in args.seeds]
    iron = f", iron {args.iron}" if args.iron else ""
    print(f"ins {params or 'defaults'}, site {args.site}{iron}, {args.seconds:.0f} s; uncalibrated: RMS from 180 s; "
          f"iron step: "
          f"RMS before the step and from 120 s after ('aft'); σ and beyond 3σ from 30 s", flush=True)
    print(f"{'vehicle':7s} {'case':12s} {'seed':>4s} {'hdg':>5s} {'tilt':>5s} {'σ med':>5s} {'>3σ':>6s} {'step':>5s} "
          f"{'hdg aft':>7s} {'tilt aft':>8s}", flush=True)
    t0 = time.perf_counter()
    rows = {}
    with Pool(args.processes) as pool:
        for job, f, aft in pool.imap(one_run, jobs):
            scen, case, seed = job[:3]
            rows[(scen, case, seed)] = (f, aft)
            a = aft or {"heading_rms": np.nan, "tilt_rms": np.nan}
            print(f"{scen:7s} {case:12s} {seed:4d} {f['heading_rms']:5.2f} {f['tilt_rms']:5.2f} {f['sigma_median']:5.2f} "
                  f"{f['beyond_3sigma']:6.2%} {f['max_step_0_1s']:5.2f} {a['heading_rms']:7.2f} {a['tilt_rms']:8.2f}",
                  flush=True)
    print("spread (min–max over seeds):")
    for scen in args.scenarios:
        for case in args.cases:
            fs = [rows[(scen, case, s)] for s in args.seeds]
            key = "heading_rms"
            hdg = [f[1][key] if case == "iron-step" else f[0][key] for f in fs]
            tilt = [f[1]["tilt_rms"] if case == "iron-step" else f[0]["tilt_rms"] for f in fs]
            beyond = [max(f[0]["beyond_3sigma"], f[1]["beyond_3sigma"] if f[1] else 0.0) for f in fs]
            label = "heading from 120 s after" if case == "iron-step" else "heading from 180 s"
            print(f"  {scen:6s} {case:12s} {label}: {min(hdg):.2f}–{max(hdg):.2f}° (mean {np.mean(hdg):.2f}°), tilt "
                  f"{min(tilt):.2f}–{max(tilt):.2f}°, beyond 3σ {min(beyond):.2%}–{max(beyond):.2%}")
    print(f"({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
