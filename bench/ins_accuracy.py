"""Accuracy of the GNSS-aided `ins` beside the unaided `mekf` on simulated moving vehicles, side by side.

    .venv/bin/python bench/ins_accuracy.py              # coordinated-turn and level-turns, 3 seeds, 200 s
    .venv/bin/python bench/ins_accuracy.py --quick      # 1 seed, 120 s

ADIS16405 errors (raw gyro and accelerometer: turn-on biases, scale and misalignment left to the filter;
magnetometer calibrated, as the daemon feeds it), 200 SPS, GNSS at 5 Hz with 1.5 m / 0.05 m/s white noise and
0.1 s latency, drawn from the scenario's truth (tests/ins_truth.py). RMS after 30 s of the tilt error (angle
of the error rotation's horizontal part) and of the true-heading error. The outage row removes the fixes for
30 s from the start of a turn and reports the worst tilt/heading error inside it, and the largest attitude
change within 1 s of the loss and of the return.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from ins_truth import (  # noqa: E402  (test helpers: truth track and fixes independent of the estimator)
    DECLINATION,
    attitude_error_ned,
    gnss_fixes,
    run_ins,
    simulated_run,
    tilt_heading_errors_deg,
)

from ahrsd.core.sample import make_sample  # noqa: E402
from ahrsd.estimator.ins import Ins  # noqa: E402
from ahrsd.estimator.mekf import FIXED_WING_MEKF_PARAMS, Mekf  # noqa: E402

OUTAGE_START = {"coordinated-turn": 90.0, "level-turns": 90.0}


def _rms(a) -> float:
    return float(np.sqrt(np.mean(np.square(a))))


def _mekf(run, params=None):
    est = Mekf(declination_rad=DECLINATION, params=params)
    t = run.truth.t_s
    return np.array([est.update(make_sample(t[k], run.gyro[k], run.accel[k], run.mag[k])).q_wxyz
                     for k in range(len(t))])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--seconds", type=float, default=200.0)
    ap.add_argument("--seeds", type=int, default=3)
    args = ap.parse_args(argv)
    if args.quick:
        args.seconds, args.seeds = 120.0, 1
    print(f"# ins vs mekf: ADIS16405 errors, 200 SPS, GNSS 5 Hz 1.5 m / 0.05 m/s, 0.1 s latency; "
          f"{args.seconds:.0f} s, seeds 1..{args.seeds}; RMS after 30 s, degrees")
    hdr = f"{'scenario':17s} {'seed':>4s} {'method':10s} {'tilt RMS':>9s} {'tilt max':>9s} {'hdg RMS':>8s} {'hdg max':>8s}"
    print(hdr)
    print("-" * len(hdr))
    outages = []
    for scenario in ("coordinated-turn", "level-turns"):
        for seed in range(1, args.seeds + 1):
            run = simulated_run(scenario, args.seconds, rate_hz=200.0, seed=seed)
            fixes = gnss_fixes(run.truth, seed=seed + 10)
            m = run.truth.t_s > 30.0
            res = run_ins(Ins(declination_rad=DECLINATION), run, fixes)
            rows = [("ins", res.q_mag), ("mekf", _mekf(run)), ("mekf-fw", _mekf(run, FIXED_WING_MEKF_PARAMS))]
            for name, q in rows:
                tilt, hdg = tilt_heading_errors_deg(q, run.truth.q_wxyz)
                print(f"{scenario:17s} {seed:4d} {name:10s} {_rms(tilt[m]):9.3f} {tilt[m].max():9.3f} "
                      f"{_rms(hdg[m]):8.3f} {np.abs(hdg[m]).max():8.3f}")
            t0 = OUTAGE_START[scenario]
            t1 = t0 + 30.0
            if args.seconds >= t1 + 10.0:
                out = run_ins(Ins(declination_rad=DECLINATION), run,
                              [(a, f) for a, f in fixes if not (t0 <= f.t_s < t1)])
                t = run.truth.t_s
                tilt, hdg = tilt_heading_errors_deg(out.q_mag, run.truth.q_wxyz)
                inside = (t >= t0) & (t < t1)
                err = np.degrees(attitude_error_ned(out.q_true, run.truth.q_wxyz))
                steps = []
                for te in (t0, t1 + 0.1):
                    k0, k1 = np.searchsorted(t, [te, te + 1.0])
                    steps.append(float(np.max(np.linalg.norm(err[k0:k1] - err[k0], axis=1))))
                outages.append((scenario, seed, tilt[inside].max(), np.abs(hdg[inside]).max(), *steps))
    if outages:
        print(f"\n# 30 s GNSS outage from the start of a turn (t = 90–120 s): worst error inside, attitude change "
              f"within 1 s of loss / return, degrees (targets: tilt ≤ 1, heading ≤ 2, steps < 0.5)")
        print(f"{'scenario':17s} {'seed':>4s} {'tilt max':>9s} {'hdg max':>8s} {'at loss':>8s} {'at return':>9s}")
        for scenario, seed, tmax, hmax, s0, s1 in outages:
            print(f"{scenario:17s} {seed:4d} {tmax:9.3f} {hmax:8.3f} {s0:8.3f} {s1:9.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
