"""Per-sample cost of ahrsd's estimators beside VQF and x-io Fusion, measured side by side in one process.

    .venv/bin/python bench/speed.py            # 16 384 samples (20 s at 819.2 SPS), best of 9
    .venv/bin/python bench/speed.py --quick    # 4 096 samples
    .venv/bin/python bench/speed.py --cpu-time --only mekf,mekf-view --no-warmup   # on a busy machine

"one at a time": one Python call per sample, as the daemon does — ahrsd's estimators through
`update(ImuSample) -> AttitudeEstimate` (`ins+gnss`: the ins also given a 5 Hz GNSS fix through
`update_gnss`, counted in its per-sample cost; plain `ins`: no fixes, unaided); `mekf-view` through the hot
path `Mekf.step(ImuSample)` (the reused view, its quaternion read, no AttitudeEstimate built:
`view.snapshot()` builds one when publishing); VQF through `VQF.update(gyr, acc, mag)` + `getQuat9D()`, Fusion
through `Ahrs.update(gyr, acc, mag)` + `get_quaternion()`. "batch": the whole array in one call
(`Mekf.run_batch`, `VQF.updateBatch`). Times are the best of `--repeat` runs, interleaved across the
estimators (the machine is shared: the minimum is the least disturbed). Ratios are against VQF measured in the same process, so they hold on any
machine. The mekf's numba JIT warm-up (import + first update) is measured in fresh processes, with the
on-disk cache cold (empty cache directory) and warm.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
RATE_HZ = 819.2


def make_samples(n: int):
    """n consecutive samples of the simulated `level-turns` scenario (ADIS16405 errors) at 819.2 SPS, and
    the 5 Hz GNSS fixes of that track (valid 0.1 s before they are handed over, interleaved by index)."""
    from ahrsd.core.gnss import make_fix
    from ahrsd.core.sample import ImuSample
    from ahrsd.simulation import DEFAULT_SITE, open_stream

    stream = open_stream("level-turns", rate_hz=RATE_HZ, seed=0, vehicle_iron=None)
    b = stream.next_block(n)
    g = np.ascontiguousarray(b.gyro_rad_s)
    a = np.ascontiguousarray(b.accel_m_s2)
    m = np.ascontiguousarray(b.mag_ut)
    t = np.ascontiguousarray(b.t_s)
    samples = [ImuSample(float(t[i]), g[i].copy(), a[i].copy(), m[i].copy()) for i in range(n)]
    v = stream.scenario.velocity_ned_m_s(t)
    ned = np.cumsum(v, axis=0) / RATE_HZ            # a few metres of track: a flat Earth is close enough here
    fixes = {}
    step = int(RATE_HZ / 5.0)
    for i in range(step, n, step):
        j = i - int(0.1 * RATE_HZ)
        fixes[i] = make_fix(t[j], DEFAULT_SITE.lat_deg + np.degrees(ned[j, 0] / 6.36e6),
                            DEFAULT_SITE.lon_deg + np.degrees(ned[j, 1] / 5.13e6), DEFAULT_SITE.alt_m - ned[j, 2],
                            v[j], h_acc_m=1.5, v_acc_m=2.5, s_acc_m_s=0.05)
    return samples, t, g, a, m, fixes


def best_of(repeat: int, fn, clock=time.perf_counter) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = clock()
        fn()
        best = min(best, clock() - t0)
    return best


def one_at_a_time(name: str, samples, g, a, m, fixes=None):
    """A callable that runs every sample through estimator `name`, one call per sample."""
    if name == "ins+gnss":
        return _ins_with_fixes(samples, fixes)
    if name in ("mekf", "thesis", "ins"):
        return _ahrsd_updates(name, samples)
    if name == "mekf-view":
        return _mekf_view_steps(samples)
    if name == "vqf":
        return _vqf_updates(g, a, m)
    if name == "fusion":
        return _fusion_updates(g, a, m)
    raise ValueError(name)


def _ins_with_fixes(samples, fixes):
    """ins through `update`, given the 5 Hz fixes (`fixes`: sample index → fix) through `update_gnss`."""
    from ahrsd.estimator import make_estimator

    def run():
        est = make_estimator("ins")
        upd = est.update
        fix_at = fixes or {}
        for i, s in enumerate(samples):
            f = fix_at.get(i)
            if f is not None:
                est.update_gnss(f)
            upd(s)

    return run


def _ahrsd_updates(name: str, samples):
    """An ahrsd estimator through `update(ImuSample) -> AttitudeEstimate`."""
    from ahrsd.estimator import make_estimator

    def run():
        est = make_estimator(name)
        upd = est.update
        for s in samples:
            upd(s)

    return run


def _mekf_view_steps(samples):
    """mekf's hot path: `Mekf.step` and its quaternion read (no AttitudeEstimate built)."""
    from ahrsd.estimator.mekf import Mekf

    def run():
        step = Mekf().step
        for s in samples:
            step(s).q_wxyz

    return run


def _vqf_updates(g, a, m):
    from vqf import VQF

    def run():
        v = VQF(1.0 / RATE_HZ)
        for i in range(len(g)):
            v.update(g[i], a[i], m[i])
            v.getQuat9D()

    return run


def _fusion_updates(g, a, m):
    import imufusion

    gd = np.degrees(g)
    ag = a / 9.80665

    def run():
        f = imufusion.Ahrs()
        f.set_sample_period(1.0 / RATE_HZ)
        for i in range(len(gd)):
            f.update(gd[i], ag[i], m[i])
            f.get_quaternion()

    return run


def batch(name: str, t, g, a, m):
    if name == "mekf":
        from ahrsd.estimator.mekf import Mekf

        return lambda: Mekf().run_batch(t, g, a, m)
    if name == "vqf":
        from vqf import VQF

        return lambda: VQF(1.0 / RATE_HZ).updateBatch(g, a, m)
    return None


_WARMUP_SNIPPET = """
import time
t0 = time.perf_counter()
import numpy as np
from ahrsd.estimator.mekf import Mekf
from ahrsd.core.sample import make_sample
t1 = time.perf_counter()
e = Mekf()
e.update(make_sample(0.0, [0, 0, 0], [0, 0, -9.81], [20, 0, 40]))
e.update(make_sample(0.001, [0, 0, 0], [0, 0, -9.81], [20, 0, 40]))
e.run_batch(np.array([0.002]), np.zeros((1, 3)), np.array([[0, 0, -9.81]]), np.array([[20.0, 0, 40]]))
t2 = time.perf_counter()
print(f"{t1 - t0:.3f} {t2 - t1:.3f}")
"""


def jit_warmup() -> dict[str, tuple[float, float]]:
    """(import s, first updates s) in a fresh process: cold = empty numba cache, warm = cache present."""
    res = {}
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        for label in ("cold", "warm"):
            out = subprocess.run([sys.executable, "-c", _WARMUP_SNIPPET], env=env, capture_output=True,
                                 text=True, cwd=REPO, check=True).stdout.split()
            res[label] = (float(out[0]), float(out[1]))
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--samples", type=int, default=16384)
    ap.add_argument("--repeat", type=int, default=9)
    ap.add_argument("--quick", action="store_true", help="4096 samples, 2 repeats, no warm-up measurement")
    ap.add_argument("--cpu-time", action="store_true",
                    help="time every estimator (VQF too) by this thread's CPU time instead of the wall clock: on a "
                         "shared machine the time the process waits for a core is then not counted")
    ap.add_argument("--only", metavar="NAMES",
                    help="comma-separated estimators to time (vqf is always timed: the ratios are against it)")
    ap.add_argument("--no-warmup", action="store_true", help="skip the JIT warm-up measurement")
    args = ap.parse_args(argv)
    clock = time.thread_time if args.cpu_time else time.perf_counter
    if args.quick:
        args.samples, args.repeat = 4096, 2
    samples, t, g, a, m, fixes = make_samples(args.samples)
    n = len(samples)
    names = ["mekf", "mekf-view", "ins", "ins+gnss", "thesis", "vqf", "fusion"]
    if args.only:
        names = [n for n in names if n in args.only.split(",") or n == "vqf"]
    avail = []
    for name in names:
        try:
            one_at_a_time(name, samples[:10], g[:10], a[:10], m[:10], fixes)()  # also warms up the JIT
            avail.append(name)
        except ImportError as exc:
            print(f"note: {name} skipped ({exc})")
    print(f"# estimator speed: {n} samples of simulated level-turns at {RATE_HZ} SPS, best of {args.repeat}"
          + (" (thread CPU time)" if args.cpu_time else ""))
    # the runs are interleaved (round r times every estimator once) so a burst of load on a shared machine falls
    # on all of them alike, not on whichever was being timed while it lasted
    runs = {name: (one_at_a_time(name, samples, g, a, m, fixes), batch(name, t, g, a, m)) for name in avail}
    for _, b in runs.values():
        if b is not None:
            b()
    best = {name: [float("inf"), float("inf")] for name in avail}
    for _ in range(args.repeat):
        for name, fns in runs.items():
            for k, fn in enumerate(fns):
                if fn is not None:
                    best[name][k] = min(best[name][k], best_of(1, fn, clock))
    rows = {name: (per / n, bat / n if runs[name][1] is not None else None) for name, (per, bat) in best.items()}
    vqf_per = rows.get("vqf", (None, None))[0]
    vqf_bat = rows.get("vqf", (None, None))[1]
    hdr = (f"{'estimator':10s} {'one-at-a-time':>14s} {'µs/sample':>10s} {'× VQF':>7s}   "
           f"{'batch':>12s} {'µs/sample':>10s} {'× VQF':>7s}")
    print(hdr)
    print("-" * len(hdr))
    for name, (per, bat) in rows.items():
        line = f"{name:10s} {1 / per:12,.0f}/s {per * 1e6:10.2f} "
        line += f"{per / vqf_per:7.2f}" if vqf_per else f"{'':7s}"
        if bat is not None:
            line += f"   {1 / bat:10,.0f}/s {bat * 1e6:10.3f} "
            line += f"{bat / vqf_bat:7.2f}" if vqf_bat else ""
        else:
            line += f"   {'n/a':>12s}"
        print(line)
    if "mekf-view" in rows and vqf_per:
        print(f"\nmekf-view (step + quaternion read): {rows['mekf-view'][0] / vqf_per:.2f}× VQF's per-sample cost "
              "(target ≤ 2×)")
    if "mekf" in rows and vqf_bat:
        print(f"mekf batch: {rows['mekf'][1] / vqf_bat:.2f}× VQF's batch cost (target ≤ 1.0×)")
    if "mekf" in rows:
        per = rows["mekf"][0]
        print(f"\nmekf one-at-a-time: {1 / per:,.0f} samples/s (target ≥ 50 000), {per * 1e6:.1f} µs/sample "
              f"= {per * RATE_HZ * 100:.2f} % of this core at {RATE_HZ} SPS"
              + (f"; {per / vqf_per:.1f}× VQF's per-sample cost (moonshot ≤ 2×)" if vqf_per else ""))
    if "mekf" in rows and "ins+gnss" in rows:
        ins_per = rows["ins+gnss"][0]
        print(f"ins with 5 Hz GNSS one-at-a-time: {ins_per * 1e6:.1f} µs/sample = {ins_per / rows['mekf'][0]:.2f}× mekf's "
              f"(target ≤ 2.5×), {ins_per * RATE_HZ * 100:.2f} % of this core at {RATE_HZ} SPS")
    if not (args.quick or args.no_warmup):
        w = jit_warmup()
        print(f"numba JIT warm-up (fresh process): cold cache: import {w['cold'][0]:.2f} s + first updates "
              f"{w['cold'][1]:.2f} s (compiling); warm cache: import {w['warm'][0]:.2f} s + first updates "
              f"{w['warm'][1]:.2f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
