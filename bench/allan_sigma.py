"""σ honesty of `ahrsd calibrate allan`: the reported 1σ of the white noise (ARW), bias instability (flicker
floor B) and rate random walk (K) against their errors on synthetic records with known terms.

    .venv/bin/python bench/allan_sigma.py            # every case (several minutes on a shared 2-core machine)
    .venv/bin/python bench/allan_sigma.py --quick    # the in-sample case and one held-out case

The records come from tests/allan_noise.py (white noise, Kasdin–Walter 1/f, random walk of the rate; generated
independently of the analysis). Each record has three gyro axes, analysed by `calibration.allan.analyse_static`.
For every term the analysis reports, z = (value − truth) / reported 1σ; an honest σ gives RMS(z) ≈ 1, about
4.6 % of |z| beyond 2 and 0.27 % beyond 3. "in-sample" is the case the σ was first measured on (docs/calibration.md);
the held-out cases differ in seeds, record length, sample rate, noise levels (down to a barely visible K) and a
sensor filter that correlates neighbouring samples (a moving average, as the chip's SENS_AVG).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import allan_noise as gen  # noqa: E402

from ahrsd.calibration.allan import analyse_static  # noqa: E402

ARW = math.radians(2.0) / 60.0        # 2 °/√h, the ADIS16405 data sheet
BIAS = math.radians(0.007)            # 0.007 °/s
K_ISSUE = 8.08e-7                     # rad/s/√s, the issue's record


@dataclass(frozen=True)
class Case:
    name: str
    split: str              # "in-sample" or "held-out"
    rate_hz: float
    hours: float
    white: float
    flicker: float = 0.0
    rrw: float = 0.0
    seeds: tuple = (0,)
    moving_average: int = 1   # samples averaged by the "sensor filter" (1: independent samples)


CASES = (
    Case("3 d, 1 Hz, N + K=8.08e-6", "in-sample", 1.0, 72.0, ARW, rrw=10 * K_ISSUE, seeds=tuple(range(12))),
    Case("3 d, 1 Hz, N + K=8.08e-6", "held-out", 1.0, 72.0, ARW, rrw=10 * K_ISSUE, seeds=tuple(range(100, 112))),
    Case("24 h, 10 Hz, N + K=8.08e-7", "held-out", 10.0, 24.0, ARW, rrw=K_ISSUE, seeds=(200, 201, 202)),
    Case("3 h, 100 Hz, N + K=8.08e-7 (barely visible)", "held-out", 100.0, 3.0, ARW, rrw=K_ISSUE,
         seeds=(300, 301, 302)),
    Case("3 h, 100 Hz, N + K=4e-6", "held-out", 100.0, 3.0, ARW, rrw=5 * K_ISSUE, seeds=(400, 401)),
    Case("1 h, 819.2 SPS, filtered N + K=2e-5", "held-out", 819.2, 1.0, ARW, rrw=2e-5, seeds=(500, 501, 502),
         moving_average=4),
    Case("24 h, 1 Hz, N + B", "held-out", 1.0, 24.0, ARW, flicker=BIAS, seeds=(600, 601, 602)),
    Case("3 d, 1 Hz, N + B + K=2.5e-6", "held-out", 1.0, 72.0, ARW, flicker=BIAS, rrw=2.5e-6,
         seeds=(700, 701, 702)),
)
QUICK = (0, 3)


def record(case: Case, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    n = int(round(case.hours * 3600.0 * case.rate_hz))
    cols = []
    for _ in range(3):
        # a moving average has unit gain at zero frequency: the white density N stays
        x = gen.white(n + case.moving_average - 1, case.rate_hz, case.white, rng)
        if case.moving_average > 1:
            x = np.convolve(x, np.full(case.moving_average, 1.0 / case.moving_average), mode="valid")
        if case.flicker:
            x = x + gen.flicker(n, case.rate_hz, case.flicker, rng)
        if case.rrw:
            x = x + gen.rate_random_walk(n, case.rate_hz, case.rrw, rng)
        cols.append(x)
    return np.column_stack(cols)


TRUTH_KEYS = (("white", "ARW", "white"), ("flicker", "B", "flicker"), ("rate_random_walk", "K", "rrw"))


def z_scores(case: Case, seed: int) -> dict[str, list[float]]:
    """Per term: the z of every axis where it was reported; 'missed' counts the axes where it was not."""
    x = record(case, seed)
    res = analyse_static(np.arange(len(x)) / case.rate_hz, gyro_rad_s=x)
    out: dict[str, list] = {}
    for p in res.parameters["gyro"].values():
        for term, _, attr in TRUTH_KEYS:
            truth = getattr(case, attr)
            if not truth:
                continue
            est = p.terms.get(term)
            if est is None:
                out.setdefault(term + " missed", []).append(1)
                continue
            out.setdefault(term, []).append((est.value - truth) / est.uncertainty)
    return out


def summary_line(label: str, z: list[float], missed: int) -> str:
    z = np.asarray(z)
    if len(z) == 0:
        return f"  {label:<5} seen 0 of {missed}"
    return (f"  {label:<5} seen {len(z):3d} of {len(z) + missed:3d}: error/σ RMS {math.sqrt(np.mean(z * z)):.2f}, "
            f"mean {np.mean(z):+.2f}, |z|>2 {np.mean(np.abs(z) > 2) * 100:4.1f} %, |z|>3 {np.mean(np.abs(z) > 3) * 100:4.1f} %,"
            f" max |z| {np.max(np.abs(z)):.2f}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--case", type=int, action="append", help="only this case (index in CASES; repeatable)")
    args = ap.parse_args()
    cases = [CASES[i] for i in (args.case or (QUICK if args.quick else range(len(CASES))))]
    pooled: dict[str, dict[str, list]] = {}
    t0 = time.perf_counter()
    for case in cases:
        acc: dict[str, list] = {}
        for seed in case.seeds:
            for key, values in z_scores(case, seed).items():
                acc.setdefault(key, []).extend(values)
        print(f"{case.split:<9} {case.name} ({len(case.seeds)} records × 3 axes)")
        for term, label, _ in TRUTH_KEYS:
            if term in acc or term + " missed" in acc:
                print(summary_line(label, acc.get(term, []), len(acc.get(term + " missed", []))))
                pool = pooled.setdefault(case.split, {})
                pool.setdefault(term, []).extend(acc.get(term, []))
                pool.setdefault(term + " missed", []).extend(acc.get(term + " missed", []))
    for split, pool in pooled.items():
        print(f"all {split}:")
        for term, label, _ in TRUTH_KEYS:
            if term in pool:
                print(summary_line(label, pool[term], len(pool[term + " missed"])))
    print(f"({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
