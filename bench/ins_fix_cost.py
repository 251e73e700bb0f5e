"""CPU per GNSS fix of ins's heading-check parts: each named `Ins` method is wrapped with a `time.process_time`
timer while a simulated run (bench/vehicle_accuracy.simulate_vehicle, magnetometer uncalibrated, antenna at the
arm) goes through `step` and `update_gnss` in arrival order, as tools/estimate_digest.py feeds it. One warm-up run,
then `--repeats` timed runs; prints µs per call (the median over the repeats) for each part and for the whole fix.

    .venv/bin/python bench/ins_fix_cost.py --vehicles car boat --seconds 60 --repeats 3
    .venv/bin/python bench/ins_fix_cost.py --parts step _stepped update_gnss _fusion._add_to_lever_arm_fit   # other parts
    .venv/bin/python bench/ins_fix_cost.py --path update --parts update update_gnss   # an estimate per sample

Compare two checkouts by running the same command in each, alternately, at the same load (the timers' own
overhead, ~1 µs a call, is in every figure).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

PARTS = ("update_gnss", "_check_heading", "_mag_rotation_check", "_learn_iron", "_magnetometer_trust_var")


def _timed_run(run, parts, path: str = "step") -> dict[str, tuple[float, int]]:
    from ahrsd.core.gnss import GnssFix
    from ahrsd.core.sample import SampleFlags, make_sample
    from ahrsd.estimator.ins import Ins
    from ahrsd.simulation import in_arrival_order

    est = Ins(declination_rad=run.declination_rad, lever_arm_m=run.lever_arm_m,
              mag_calibration_sigma_rad=run.mag_calibration_sigma_rad)
    spent = {p: [0.0, 0] for p in parts}
    for p in parts:
        *path_to, name = p.split(".")      # a part's method: "_fusion._add_to_lever_arm_fit"
        owner = est
        for attr in path_to:
            owner = getattr(owner, attr)
        inner = getattr(owner, name)

        def timed(*args, _inner=inner, _acc=spent[p], **kw):
            t0 = time.process_time()
            try:
                return _inner(*args, **kw)
            finally:
                _acc[0] += time.process_time() - t0
                _acc[1] += 1
        setattr(owner, name, timed)
    t, g, a, m = run.t_s, run.gyro_rad_s, run.accel_m_s2, run.mag_ut
    samples = (make_sample(t[k], g[k], a[k], m[k], flags=SampleFlags.NEW_DATA) for k in range(len(t)))
    for item in in_arrival_order(samples, run.fixes):
        if isinstance(item, GnssFix):
            est.update_gnss(item)
        elif path == "update":
            est.update(item)        # an AttitudeEstimate built at every sample, as most tests' harnesses read
        else:
            est.step(item)
    return {p: (s, n) for p, (s, n) in spent.items()}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--vehicles", nargs="+", default=["car", "boat"])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--path", choices=("step", "update"), default="step",
                    help="the samples through step (the daemon's) or update (an estimate built at each)")
    ap.add_argument("--parts", nargs="+", default=list(PARTS), help="the Ins methods (a part's: `_fusion.name`) to time (default: %(default)s)")
    args = ap.parse_args(argv)
    from vehicle_accuracy import simulate_vehicle

    for vehicle in args.vehicles:
        run = simulate_vehicle(vehicle, args.seconds, args.seed, None, lever_arm=True, mag="uncalibrated")
        _timed_run(run, args.parts, args.path)      # warm-up: the compiled kernels load
        per_call = {p: [] for p in args.parts}
        calls = {}
        for _ in range(args.repeats):
            for p, (s, n) in _timed_run(run, args.parts, args.path).items():
                per_call[p].append(1e6 * s / max(n, 1))
                calls[p] = n
        print(f"{vehicle}: " + "  ".join(f"{p} {statistics.median(v):.1f} µs ×{calls[p]}"
                                         for p, v in per_call.items()), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
