"""Memory and time of `ahrsd calibrate allan` on a day-long recording, and the terms it finds against the truth.

    .venv/bin/python bench/allan.py                      # 24 h at 819.2 SPS (70.8 M samples per axis)
    .venv/bin/python bench/allan.py --hours 1            # quicker
    .venv/bin/python bench/allan.py --gzip --keep DIR    # a .csv.gz recording, kept in DIR

A synthetic static recording is written to a temporary file a chunk at a time (never held in memory): gyro
white noise (ARW 2 °/√h) + a first-order Gauss–Markov bias (σ 0.007 °/s, Tc 100 s) + a rate random walk
(K 8.08e-7 rad/s/√s) on each axis; accelerometer (VRW 0.2 m/s/√h) and magnetometer (0.125 µT per sample)
white noise. Then the CLI runs on it in a child process (`ahrsd calibrate allan FILE --json --dry-run`, the console
script beside this interpreter); its peak RSS is that child's ru_maxrss from os.wait4 (measured by the kernel).
This process imports no numpy and writes the recording in another child, so the fork it starts the CLI from
adds only a few MB to that figure. The time to only parse the file (iter_recording_chunks) is printed beside.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ARW = math.radians(2.0) / 60.0
GM_SIGMA, GM_TC_S = math.radians(0.007), 100.0
K_RRW = 8.08e-7
VRW = 0.2 / 60.0
MAG_SIGMA_UT = 0.125
CHUNK = 1 << 20


def write_recording(path: Path, hours: float, rate_hz: float, seed: int, gzip_level: int | None) -> int:
    """Write the synthetic recording in chunks; returns the number of samples."""
    import numpy as np
    from scipy.signal import lfilter

    from ahrsd.drivers.recording import RECORDING_HEADER

    rng = np.random.default_rng(seed)
    n_total = int(round(hours * 3600.0 * rate_hz))
    phi = math.exp(-1.0 / (rate_hz * GM_TC_S))
    gm_state = rng.standard_normal(3) * GM_SIGMA * phi
    rrw_state = np.zeros(3)
    if gzip_level is None:
        f = open(path, "w", encoding="ascii", newline="\n")
    else:
        import gzip

        f = gzip.open(path, "wt", compresslevel=gzip_level, encoding="ascii", newline="\n")
    fmt = ["%.10f"] + ["%.6e"] * 9
    with f:
        f.write(RECORDING_HEADER + "\n")
        for start in range(0, n_total, CHUNK):
            n = min(CHUNK, n_total - start)
            t = (start + np.arange(n)) / rate_hz
            white = rng.standard_normal((n, 3)) * ARW * math.sqrt(rate_hz)
            drive = rng.standard_normal((n, 3)) * GM_SIGMA * math.sqrt(1.0 - phi * phi)
            gm = np.empty((n, 3))
            for i in range(3):
                gm[:, i], zi = lfilter([1.0], [1.0, -phi], drive[:, i], zi=[gm_state[i]])
                gm_state[i] = zi[0]
            rrw = rrw_state + np.cumsum(rng.standard_normal((n, 3)) * K_RRW / math.sqrt(rate_hz), axis=0)
            rrw_state = rrw[-1].copy()
            gyro = white + gm + rrw
            accel = rng.standard_normal((n, 3)) * VRW * math.sqrt(rate_hz) + [0.0, 0.0, -9.80665]
            mag = rng.standard_normal((n, 3)) * MAG_SIGMA_UT + [20.0, 0.0, 40.0]
            np.savetxt(f, np.column_stack([t, gyro, accel, mag]), fmt=fmt, delimiter=",")
            print(f"\r  writing {start + n:,}/{n_total:,} samples", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    return n_total


def parse_only_s(path: Path) -> float:
    from ahrsd.drivers.recording import iter_recording_chunks

    t0 = time.perf_counter()
    for _ in iter_recording_chunks(path):
        pass
    return time.perf_counter() - t0


def run_child(argv: list[str]) -> tuple[str, float, float]:
    """(stdout, wall s, peak RSS MB) of one child process, its RSS from the kernel's rusage of that child."""
    t0 = time.perf_counter()
    with tempfile.TemporaryFile("w+") as out:
        proc = subprocess.Popen(argv, stdout=out, stderr=sys.stderr, text=True)
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        wall = time.perf_counter() - t0
        out.seek(0)
        text = out.read()
    if proc.returncode != 0:
        raise RuntimeError(f"{argv[0]} exited {proc.returncode}")
    return text, wall, usage.ru_maxrss / 1024.0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--hours", type=float, default=24.0)
    ap.add_argument("--rate-hz", type=float, default=819.2)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--gzip", action="store_true", help="write and read a .csv.gz (gzip level 1)")
    ap.add_argument("--keep", metavar="DIR", help="write the recording in DIR and keep it (default: a temp dir)")
    ap.add_argument("--skip-parse", action="store_true", help="do not time the parse-only pass")
    ap.add_argument("--write-only", metavar="FILE", help=argparse.SUPPRESS)   # the child that writes
    ap.add_argument("--parse-only", metavar="FILE", help=argparse.SUPPRESS)   # the child that only parses
    args = ap.parse_args()
    if args.write_only:
        n = write_recording(Path(args.write_only), args.hours, args.rate_hz, args.seed, 1 if args.gzip else None)
        print(n)
        return 0
    if args.parse_only:
        print(parse_only_s(Path(args.parse_only)))
        return 0

    workdir = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="ahrsd-allan-bench-"))
    workdir.mkdir(parents=True, exist_ok=True)
    path = workdir / ("static.csv.gz" if args.gzip else "static.csv")
    me = [sys.executable, __file__, "--hours", str(args.hours), "--rate-hz", str(args.rate_hz),
          "--seed", str(args.seed)] + (["--gzip"] if args.gzip else [])
    try:
        text, write_s, _ = run_child(me + ["--write-only", str(path)])
        n = int(text)
        size_gb = path.stat().st_size / 1e9
        parse_s = math.nan if args.skip_parse else float(run_child(me + ["--parse-only", str(path)])[0])
        ahrsd = str(Path(sys.executable).with_name("ahrsd"))   # the console script beside this interpreter
        text, wall_s, peak_mb = run_child([ahrsd, "calibrate", "allan", str(path), "--json", "--dry-run"])
        out = json.loads(text)
    finally:
        if not args.keep:
            for p in workdir.iterdir():
                p.unlink()
            workdir.rmdir()

    print(f"recording: {args.hours:g} h at {args.rate_hz:g} SPS = {n:,} samples per axis, {size_gb:.2f} GB "
          f"({'gzip' if args.gzip else 'csv'}), written in {write_s:.0f} s")
    print(f"ahrsd calibrate allan: {wall_s:.0f} s wall, peak RSS {peak_mb:.0f} MB "
          f"(parse only: {parse_s:.0f} s); CPU {os.cpu_count()} cores shared, load {os.getloadavg()[0]:.1f}")
    print(f"{'gyro':>6} {'ARW':>10} {'truth':>10} {'GM σ':>10} {'truth':>10} {'GM Tc s':>8} {'K':>10} {'truth':>10}  "
          "terms")
    for ax in "xyz":
        g = out["gyro"][ax]
        seen = [name for name, t in g["terms"].items() if t is not None]

        def fmt(v):
            return f"{v:10.3e}" if v is not None else f"{'-':>10}"
        tc = f"{g['gauss_markov_tau_s']:8.1f}" if g["gauss_markov_tau_s"] else f"{'-':>8}"
        print(f"{ax:>6} {fmt(g['white_noise'])} {ARW:10.3e} {fmt(g['gauss_markov_sigma'])} {GM_SIGMA:10.3e} {tc} "
              f"{fmt(g['rate_random_walk'])} {K_RRW:10.3e}  {', '.join(seen)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
