"""How far a calibrated run without an iron step keeps the iron-step test (estimator/mag_step.py) from its gate: the
largest statistic |mean after − mean before| / σ the detector computes over the run, up to each of `--spans`, with
its gate (tests/test_mag_step.py's no-step runs: simulate_vehicle at the default site, every sample stepped, the
checks at the fixes). `--drop` leaves one of the test's variance terms out by telling the detector a zero for it
(yaw: the filter's yaw variance; gyro: the vertical gyro bias and its random walk; tilt: the tilt's share through
the dip; turn: the magnetometer's heading-dependent error, whose variance only the turn term reads), as the
mutations iron-step-yaw-variance, iron-step-gyro-variance and iron-step-turn-widens do.

    .venv/bin/python bench/mag_step_margin.py --scenarios boat car --seed 2 --seconds 240 --spans 150 240 --drop none turn yaw gyro tilt
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

_ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(_ROOT), str(_ROOT / "tests")]     # bench.vehicle_accuracy, and tests/support's thinned run

# the positions of the variances among MagStepDetector.add's arguments after t_s, innovation and yaw
_TOLD = {"none": (), "yaw": (3,), "turn": (4,), "tilt": (5,), "gyro": (6, 7)}


def largest_statistics(scenario: str, seed: int, seconds: float, spans_s: list[float], drop: str) -> tuple[list, int]:
    """(the largest statistic up to each span with its time, s), and the detections over the whole run."""
    import numpy as np

    from ahrsd.estimator import mag_step
    from bench.vehicle_accuracy import simulate_vehicle
    from support.thinned_ins import run_ins_thinned

    seen = []
    original = mag_step.MagStepDetector.add

    def add(self, t_s, *told):
        told = [0.0 if i + 1 in _TOLD[drop] else v for i, v in enumerate(told)]
        step = original(self, t_s, *told)
        seen.append((t_s, self.statistic))
        return step

    mag_step.MagStepDetector.add = add
    try:
        run = simulate_vehicle(scenario, seconds, seed, None)
        ins = run_ins_thinned(run, len(run.t_s)).ins
    finally:
        mag_step.MagStepDetector.add = original
    stats = np.array([(t, s) for t, s in seen if math.isfinite(s)])
    out = []
    for span in spans_s:
        within = stats[stats[:, 0] <= span]
        k = int(np.argmax(within[:, 1]))
        out.append((float(within[k, 1]), float(within[k, 0])))
    return out, ins.heading_report().mag_steps


def main() -> None:
    from ahrsd.estimator.mag_step import MagStepDetector

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenarios", nargs="+", default=["boat", "car"])
    ap.add_argument("--seed", type=int, default=2)
    ap.add_argument("--seconds", type=float, default=240.0)
    ap.add_argument("--spans", nargs="+", type=float, default=[150.0, 240.0], help="spans from the start, s")
    ap.add_argument("--drop", nargs="+", choices=sorted(_TOLD), default=["none"])
    args = ap.parse_args()
    print(f"gate {MagStepDetector().gate_sigma:g} sigma")
    for drop in args.drop:
        for scenario in args.scenarios:
            largest, steps = largest_statistics(scenario, args.seed, args.seconds, args.spans, drop)
            figures = ", ".join(f"to {span:g} s {value:.2f} sigma at {t:.0f} s"
                                for span, (value, t) in zip(args.spans, largest))
            print(f"drop {drop:5s} {scenario:5s} seed {args.seed}: {figures}; detections over {args.seconds:g} s: {steps}",
                  flush=True)


if __name__ == "__main__":
    main()
