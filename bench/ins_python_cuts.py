"""µs per call of ins's per-sample and per-fix Python before and after session 34's cuts (insfix34), the two forms
timed in one process, interleaved (timeit, the best of --repeats), on the state a simulated car run leaves: on a
shared machine whose load moves CPU figures by ±30 % from one minute to the next, a whole-run A/B cannot resolve a
few µs; this can. Each line: what the cut replaced, its µs before → after, and how often ins runs it.

    .venv/bin/python bench/ins_python_cuts.py
    .venv/bin/python bench/ins_python_cuts.py --number 20000 --repeats 5
"""

from __future__ import annotations

import argparse
import math
import sys
import timeit
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def _state():
    """An Ins after 30 s of the simulated car (magnetometer uncalibrated, antenna at the arm) and its view."""
    from vehicle_accuracy import simulate_vehicle

    from ahrsd.core.gnss import GnssFix
    from ahrsd.core.sample import SampleFlags, make_sample
    from ahrsd.estimator.ins import Ins
    from ahrsd.simulation import in_arrival_order

    run = simulate_vehicle("car", 30.0, 0, None, lever_arm=True, mag="uncalibrated")
    est = Ins(declination_rad=run.declination_rad, lever_arm_m=run.lever_arm_m,
              mag_calibration_sigma_rad=run.mag_calibration_sigma_rad)
    t, g, a, m = run.t_s, run.gyro_rad_s, run.accel_m_s2, run.mag_ut
    view = None
    samples = (make_sample(t[k], g[k], a[k], m[k], flags=SampleFlags.NEW_DATA) for k in range(len(t)))
    for item in in_arrival_order(samples, run.fixes):
        if isinstance(item, GnssFix):
            est.update_gnss(item)
        else:
            view = est.step(item)
    return est, view


def _pairs(est):
    """(name, how often, before, after): each a zero-argument callable doing one call's work."""
    from ahrsd.estimator import rotations
    from ahrsd.estimator.heading_supervision import _finite3

    x = est._x
    rate = np.array([0.01, -0.2, 0.3])
    m_body = np.array([20.0, -3.0, 40.0])
    return [
        ("skew of one 3-vector", "every velocity fix", lambda: rotations.skew(rate[None])[0],
         lambda: rotations.skew(rate)),
        ("finite 3-vector", "2 a heading check", lambda: bool(np.all(np.isfinite(m_body))), lambda: _finite3(m_body)),
        ("the attitude as a DCM (heading check)", "every heading check",
         lambda: np.asarray(rotations.quat_to_dcm(x["q"]), dtype=float),
         lambda: rotations.quat_to_dcm(x["q"])),
    ]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--number", type=int, default=20000, help="calls per timing")
    ap.add_argument("--repeats", type=int, default=5, help="timings per form, interleaved; the best is kept")
    args = ap.parse_args(argv)
    est, _ = _state()
    for name, how_often, before, after in _pairs(est):
        best = [math.inf, math.inf]
        for _ in range(args.repeats):
            for i, fn in enumerate((before, after)):
                best[i] = min(best[i], timeit.timeit(fn, number=args.number) / args.number)
        print(f"{name:46s} {1e6 * best[0]:6.2f} → {1e6 * best[1]:6.2f} µs  ({how_often})", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
