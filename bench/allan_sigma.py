"""σ honesty of `ahrsd calibrate allan`: the reported 1σ of the white noise (ARW), bias instability (flicker
floor B) and rate random walk (K) against their errors on synthetic records with known terms.

    .venv/bin/python bench/allan_sigma.py            # every case (several minutes on a shared 2-core machine)
    .venv/bin/python bench/allan_sigma.py --quick    # the in-sample case and one held-out case
    .venv/bin/python bench/allan_sigma.py --table    # docs/calibration.md's accuracy table: 24 h at 1 Hz, 30 seeds
                                                     # (--case N: only row N of it)

The records come from tests/allan_noise.py (white noise, Kasdin–Walter 1/f, random walk of the rate; generated
independently of the analysis). Each record has three gyro axes, analysed by `calibration.allan.analysis.analyse_static`.
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
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import allan_noise as gen  # noqa: E402

from ahrsd.calibration.allan.analysis import analyse_static  # noqa: E402

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
    gauss_markov: float = 0.0
    gm_tc_s: float = 100.0
    seeds: tuple = (0,)
    moving_average: int = 1   # samples averaged by the "sensor filter" (1: independent samples)
    flicker_oversample: int = 8   # 1/f generated this many times faster and averaged down (see record)


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
TABLE = (
    Case("24 h, 1 Hz, N + B", "table", 1.0, 24.0, ARW, flicker=BIAS, seeds=tuple(range(800, 830))),
    Case("24 h, 1 Hz, N + K=8.08e-6", "table", 1.0, 24.0, ARW, rrw=10 * K_ISSUE, seeds=tuple(range(830, 860))),
    Case("24 h, 1 Hz, N + Gauss–Markov (Tc 100 s)", "table", 1.0, 24.0, ARW, gauss_markov=BIAS,
         seeds=tuple(range(860, 890))),
)


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
            # The discrete 1/f generator's spectrum rises above 1/f near its Nyquist frequency (its Allan
            # variance is 1.45× the floor at one sample): generated faster and averaged over each sample
            # interval, as a sensor integrates, it is 1/f over the band the analysis sees.
            k = case.flicker_oversample
            x = x + gen.flicker(n * k, case.rate_hz * k, case.flicker, rng).reshape(n, k).mean(axis=1)
        if case.rrw:
            x = x + gen.rate_random_walk(n, case.rate_hz, case.rrw, rng)
        if case.gauss_markov:
            x = x + gen.gauss_markov(n, case.rate_hz, case.gauss_markov, case.gm_tc_s, rng)
        cols.append(x)
    return np.column_stack(cols)


TRUTH_KEYS = (("white", "ARW", "white"), ("flicker", "B", "flicker"), ("rate_random_walk", "K", "rrw"),
              ("gauss_markov", "σ_GM", "gauss_markov"))


def z_scores(case: Case, seed: int) -> dict[str, list]:
    """Per term: (z, relative error, relative 1σ) of every axis where it was reported; 'missed' counts the
    axes where it was not."""
    x = record(case, seed)
    res = analyse_static(np.arange(len(x)) / case.rate_hz, gyro_rad_s=x)
    out: dict[str, list] = {}
    injected = {term for term, _, attr in TRUTH_KEYS if getattr(case, attr)}
    for p in res.parameters["gyro"].values():
        for term in set(p.terms) - injected:
            out.setdefault("also reported", []).append(term)
        for term, _, attr in TRUTH_KEYS:
            truth = getattr(case, attr)
            if not truth:
                continue
            est = p.terms.get(term)
            if est is None:
                out.setdefault(term + " missed", []).append(1)
                continue
            out.setdefault(term, []).append(((est.value - truth) / est.uncertainty, est.value / truth - 1.0,
                                             est.uncertainty / truth))
    return out


def summary_line(label: str, rows: list, missed: int) -> str:
    if len(rows) == 0:
        return f"  {label:<5} seen 0 of {missed}"
    z, rel, sigma = np.asarray(rows).T
    return (f"  {label:<5} seen {len(z):3d} of {len(z) + missed:3d}: error/σ RMS {math.sqrt(np.mean(z * z)):.2f}, "
            f"mean {np.mean(z):+.2f}, |z|>2 {np.mean(np.abs(z) > 2) * 100:4.1f} %, |z|>3 {np.mean(np.abs(z) > 3) * 100:4.1f} %,"
            f" max |z| {np.max(np.abs(z)):.2f}; error {math.sqrt(np.mean(rel * rel)) * 100:.2g} % rms, "
            f"{np.max(np.abs(rel)) * 100:.2g} % max, 1σ {np.mean(sigma) * 100:.2g} % mean")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--table", action="store_true")
    ap.add_argument("--raw-flicker", action="store_true", help="1/f from the generator at the sample rate itself")
    ap.add_argument("--case", type=int, action="append", help="only this case (index in CASES, or in TABLE with --table; repeatable)")
    args = ap.parse_args()
    cases = [CASES[i] for i in (args.case or (QUICK if args.quick else range(len(CASES))))]
    if args.table:
        cases = [TABLE[i] for i in (args.case or range(len(TABLE)))]
    if args.raw_flicker:
        cases = [replace(c, flicker_oversample=1) for c in cases]
    pooled: dict[str, dict[str, list]] = {}
    t0 = time.perf_counter()
    for case in cases:
        acc: dict[str, list] = {}
        for seed in case.seeds:
            for key, values in z_scores(case, seed).items():
                acc.setdefault(key, []).extend(values)
        print(f"{case.split:<9} {case.name} ({len(case.seeds)} records × 3 axes)")
        extra = acc.get("also reported", [])
        print("  terms not injected but reported: " + (", ".join(f"{t} on {extra.count(t)} axes" for t in sorted(set(extra)))
                                                      or "none"))
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
