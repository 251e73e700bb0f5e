"""`ins` across a gap in the samples: the filter restarts after it keeping what it had learned
(InsParams.reinit_dt_s), levelled on the sample after the gap while the vehicle moves. Per run: the true-heading and
tilt RMS over the 30 s after the gap and from then to the end, the largest heading error in the 30 s after it, and
the share of heading errors beyond 3σ after the gap — the same runs as `tools/estimate_digest.py --gap-s` (the
simulated boat, car and plane of bench/vehicle_accuracy.py at the default site, the antenna at the vehicle's arm and
the filter told it, no samples for `--gap-s` from 40 % of the run, the fixes still offered), longer and with the
truth. Weighs a change to how `ins` starts (docs/estimator.md "turn37"): run it on two checkouts and compare.

    python bench/gap_restart.py --seconds 300 --gap-s 3 --seeds 0 1
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.vehicle_accuracy import simulate_vehicle, tilt_heading_errors_deg  # noqa: E402

AFTER_S = 30.0


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if x.size else float("nan")


def gap_run(vehicle: str, mag: str, seed: int, seconds: float, gap_s: float) -> dict:
    """One run with the gap; the figures after it (degrees, the share in %)."""
    from ahrsd.core.gnss import GnssFix
    from ahrsd.core.sample import SampleFlags, make_sample
    from ahrsd.estimator.ins import Ins
    from ahrsd.simulation import in_arrival_order

    run = simulate_vehicle(vehicle, seconds, seed, None, lever_arm=True, mag=mag)
    est = Ins(declination_rad=run.declination_rad, lever_arm_m=run.lever_arm_m,
              mag_calibration_sigma_rad=run.mag_calibration_sigma_rad)
    t, g, a, m = run.t_s, run.gyro_rad_s, run.accel_m_s2, run.mag_ut
    gap_from_s = t[0] + 0.4 * (t[-1] - t[0])
    gap_to_s = gap_from_s + gap_s
    kept = [k for k in range(len(t)) if not gap_from_s <= t[k] < gap_to_s]
    q = np.full((len(t), 4), np.nan)
    sigma_yaw_deg = np.full(len(t), np.nan)
    index = iter(kept)
    samples = (make_sample(t[k], g[k], a[k], m[k], flags=SampleFlags.NEW_DATA) for k in kept)
    for item in in_arrival_order(samples, run.fixes):
        if isinstance(item, GnssFix):
            est.update_gnss(item)
            continue
        k = next(index)
        e = est.update(item)
        q[k] = e.q_wxyz
        sigma_yaw_deg[k] = np.degrees(e.sigma_rpy_rad[2])
    after = np.isfinite(q[:, 0]) & (t >= gap_to_s)
    tilt, hdg = tilt_heading_errors_deg(q[after], run.truth_q_wxyz[after], run.declination_rad)
    first = t[after] < gap_to_s + AFTER_S
    return {"hdg_first": _rms(hdg[first]), "tilt_first": _rms(tilt[first]),
            "hdg_later": _rms(hdg[~first]), "tilt_later": _rms(tilt[~first]),
            "hdg_max_first": float(np.max(np.abs(hdg[first]))) if np.any(first) else float("nan"),
            "beyond_3sigma_pct": 100.0 * float(np.mean(np.abs(hdg) > 3.0 * sigma_yaw_deg[after]))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=300.0)
    ap.add_argument("--gap-s", type=float, default=3.0)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--vehicles", nargs="+", default=["boat", "car", "plane"])
    args = ap.parse_args(argv)
    if not 0.0 < args.gap_s < 0.5 * args.seconds:
        ap.error("--gap-s must be above 0 and below half of --seconds")
    logging.disable(logging.WARNING)
    from ahrsd.core.wmm import fixed_date
    from tools.estimate_digest import FIELD_DATE

    print(f"gap {args.gap_s:g} s at 40 % of {args.seconds:g} s; heading / tilt RMS over the {AFTER_S:g} s after the"
          " gap and later, the largest heading error in those 30 s, beyond 3σ after the gap")
    with fixed_date(FIELD_DATE):
        for vehicle in args.vehicles:
            for mag in ("uncalibrated", "calibrated"):
                for seed in args.seeds:
                    r = gap_run(vehicle, mag, seed, args.seconds, args.gap_s)
                    print(f"{vehicle:5s} {mag:12s} seed {seed}: 0-30 s {r['hdg_first']:6.2f} / {r['tilt_first']:4.2f}°"
                          f" (largest {r['hdg_max_first']:6.2f}°)  later {r['hdg_later']:5.2f} / {r['tilt_later']:4.2f}°"
                          f"  beyond 3σ {r['beyond_3sigma_pct']:5.2f} %", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
