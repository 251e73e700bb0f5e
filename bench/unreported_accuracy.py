"""`ins` on the vehicles when the receiver reports no accuracies (NMEA), by the default 1σ it is weighted with.

    .venv/bin/python bench/unreported_accuracy.py            # boat, car, plane × 2 sites × 3 seeds (~2 min)
    .venv/bin/python bench/unreported_accuracy.py --quick    # 1 seed, 60° N only

The runs of bench/accuracy.py --vehicles (bench/vehicle_accuracy.py: same data, same seeds), with the fixes
turned into what an NMEA receiver delivers: no h_acc/v_acc/s_acc (NaN) and no vertical velocity. Columns:

- `reported`: the fixes as the simulated u-blox reports them (1.5 m / 2.5 m / 0.05 m/s, its true σ), for reference;
- `ins before`: NaN weighted by the InsParams defaults before they were unified (3 m / 6 m / 0.3 m/s: a live NMEA fix);
- `rec before`: NaN filled by the recording reader's old defaults (2.5 m / 5 m / 0.1 m/s: the same fix replayed);
- `now`: NaN, weighted by ahrsd.core.gnss's defaults (both paths).

The old defaults are applied by filling the fixes (`with_default_accuracies`), which weighs exactly as the old
parameters did. Tilt and true-heading RMS after 30 s, degrees (targets ≤ 0.3° / ≤ 0.5°).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.vehicle_accuracy import (SETTLE_S, VEHICLE_SCENARIOS, VEHICLE_SITES, _rms, run_ins,  # noqa: E402
                                    simulate_vehicle, tilt_heading_errors_deg)

OLD_DEFAULTS = {"ins before": (3.0, 6.0, 0.3), "rec before": (2.5, 5.0, 0.1)}


def as_nmea(fix):
    """The fix without what NMEA does not carry: accuracies and vertical velocity."""
    vel = np.array(fix.vel_ned_m_s, dtype=float)
    vel[2] = math.nan
    return dataclasses.replace(fix, h_acc_m=math.nan, v_acc_m=math.nan, s_acc_m_s=math.nan, vel_ned_m_s=vel)


def variants(run):
    from ahrsd.core.gnss import with_default_accuracies

    nmea = [as_nmea(f) for f in run.fixes]
    out = {"reported": run.fixes}
    for name, (h, v, s) in OLD_DEFAULTS.items():
        out[name] = [with_default_accuracies(f, h, v, s) for f in nmea]
    out["now"] = nmea
    return out


def main(argv=None) -> int:
    from ahrsd.core.gnss import DEFAULT_H_ACC_M, DEFAULT_S_ACC_M_S, DEFAULT_V_ACC_M

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="1 seed, the 60° N site only")
    ap.add_argument("--seeds", type=int, default=3)
    args = ap.parse_args(argv)
    seeds = 1 if args.quick else args.seeds
    sites = {"60N": VEHICLE_SITES["60N"]} if args.quick else VEHICLE_SITES
    print(f"# ins on NMEA-like fixes (no accuracies, no vertical velocity); now = core defaults "
          f"{DEFAULT_H_ACC_M} m / {DEFAULT_V_ACC_M} m / {DEFAULT_S_ACC_M_S} m/s")
    names = ["reported", *OLD_DEFAULTS, "now"]
    hdr = f"{'vehicle':8s} {'site':8s} {'seed':>4s} " + "".join(f"{n + ' tilt':>16s}{'hdg':>7s}" for n in names)
    print(hdr)
    print("-" * len(hdr))
    rows = {n: [] for n in names}
    for scen in VEHICLE_SCENARIOS:
        for label, text in sites.items():
            for seed in range(1, seeds + 1):
                run = simulate_vehicle(scen, 200.0, seed, text)
                line = f"{scen:8s} {label:8s} {seed:4d} "
                for n, fixes in variants(run).items():
                    q = run_ins(dataclasses.replace(run, fixes=fixes))
                    tilt, hdg = tilt_heading_errors_deg(q, run.truth_q_wxyz, run.declination_rad)
                    settle = run.t_s >= SETTLE_S
                    r = (_rms(tilt[settle]), _rms(hdg[settle]))
                    rows[n].append(r)
                    line += f"{r[0]:16.3f}{r[1]:7.3f}"
                print(line, flush=True)
    for n in names:
        a = np.array(rows[n])
        print(f"{n:12s} worst tilt {a[:, 0].max():.3f} heading {a[:, 1].max():.3f}   "
              f"mean tilt {a[:, 0].mean():.3f} heading {a[:, 1].mean():.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
