"""CPU of the Allan analysis, this checkout's against another's (e.g. main's), alternated in one process.

    git archive main | tar -x -C OLD_DIR       # another tree, e.g. main's
    nice -n 5 .venv/bin/python bench/allan_cpu.py --old OLD_DIR --repeats 3

The other tree's package is imported beside this one as `ahrsd_old` (the Allan modules import each other and
the package relatively), so both run the same inputs in the same process, old and new alternated, and the
ratio is the figure (the seconds move with the load). Inputs, like the Allan tests': `analyse_static` of a 3 h
100 Hz record of gyro (white + rate random walk), accelerometer and magnetometer (test_cal_allan's issue record),
of 10 min of white noise plus a Gauss–Markov bias on three axes, and of the same through a 5-sample window
(a sensor filter); the results are checked equal (every number) before the times are printed.
"""

from __future__ import annotations

import argparse
import importlib
import math
import sys
import time
import types

import numpy as np

ARW = math.radians(2.0) / 60.0
K_RRW = 8.08e-7


def _inputs() -> dict[str, tuple]:
    rate = 100.0
    rng = np.random.default_rng(1)
    n = int(3 * 3600 * rate)
    gyro = (rng.standard_normal((n, 3)) * ARW * math.sqrt(rate)
            + np.cumsum(rng.standard_normal((n, 3)), axis=0) * K_RRW / math.sqrt(rate))
    accel = rng.standard_normal((n, 3)) * 0.2 / 60.0 * math.sqrt(rate) + [0.0, 0.0, -9.81]
    mag = rng.standard_normal((n, 3)) * 0.125 + [20.0, 0.0, 40.0]
    out = {"issue 3 h": (np.arange(n) / rate, gyro, accel, mag)}
    from scipy.signal import lfilter

    n = int(600 * rate)
    phi = math.exp(-1.0 / (rate * 5.0))
    gm = lfilter([1.0], [1.0, -phi], rng.standard_normal((n, 3)) * 2e-4 * math.sqrt(1 - phi * phi), axis=0)
    x = rng.standard_normal((n, 3)) * 1e-3 * math.sqrt(rate) + gm
    out["white + GM 10 min"] = (np.arange(n) / rate, x, None, None)
    window = lfilter(np.ones(5) / 5.0, [1.0], rng.standard_normal((n + 4, 3)) * 1e-3 * math.sqrt(rate), axis=0)[4:]
    out["5-sample window 10 min"] = (np.arange(n) / rate, window, None, None)
    return out


def _same(a, b) -> bool:
    import dataclasses

    if isinstance(a, np.ndarray):
        return isinstance(b, np.ndarray) and a.shape == b.shape and a.tobytes() == b.tobytes()
    if dataclasses.is_dataclass(a):
        return type(a).__name__ == type(b).__name__ and all(
            _same(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(a))
    if isinstance(a, dict):
        return isinstance(b, dict) and sorted(a, key=repr) == sorted(b, key=repr) and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, float):
        return np.float64(a).tobytes() == np.float64(b).tobytes()
    return a == b


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--old", required=True, help="the other checkout's tree (its calibration/allan is compared)")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    old_pkg = types.ModuleType("ahrsd_old")
    old_pkg.__path__ = [args.old]
    sys.modules["ahrsd_old"] = old_pkg
    analyses = {"old": importlib.import_module("ahrsd_old.calibration.allan.analysis").analyse_static,
                "new": importlib.import_module("ahrsd.calibration.allan.analysis").analyse_static}
    inputs = _inputs()
    cpu = {(name, which): [] for name in inputs for which in analyses}
    for name, record in inputs.items():
        results = {which: fn(*record) for which, fn in analyses.items()}   # also the kernels' first calls
        if not _same(results["old"], results["new"]):
            sys.exit(f"{name}: old and new results differ")
    for r in range(args.repeats):
        order = ("old", "new") if r % 2 == 0 else ("new", "old")
        for name, record in inputs.items():
            for which in order:
                t0 = time.process_time()
                analyses[which](*record)
                cpu[(name, which)].append(time.process_time() - t0)
    print("every result identical, old and new")
    print(f"{'input':26s} {'old CPU-s':>10s} {'new CPU-s':>10s} {'new/old':>8s}   (median of {args.repeats})")
    total = {"old": 0.0, "new": 0.0}
    for name in inputs:
        med = {w: float(np.median(cpu[(name, w)])) for w in analyses}
        total = {w: total[w] + med[w] for w in total}
        print(f"{name:26s} {med['old']:10.2f} {med['new']:10.2f} {med['new'] / med['old']:8.2f}")
    print(f"{'all':26s} {total['old']:10.2f} {total['new']:10.2f} {total['new'] / total['old']:8.2f}")


if __name__ == "__main__":
    main()
