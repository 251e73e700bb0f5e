"""The on-vehicle sample log's disk rate and writer cost: samples from the simulated ADIS16405 through the real
driver (quantised and scaled as on the vehicle) at 819.2 SPS, logged by SampleLog as .csv.gz, at each gzip level
asked for, side by side.

    .venv/bin/python bench/log_size.py [--seconds 120] [--scenario level-turns] [--levels 1,4,6,9] [--paced]

--paced: the samples are put at 819.2 SPS in real time, in bursts of 50 ms as the daemon's reader does, so
the writer works in the daemon's small blocks (slower per sample than in bulk: docs/logging.md has both); each level then
takes --seconds of wall time. Prints per level the compressed and uncompressed bytes per sample, MB per hour at 819.2 SPS, how long 1 GB
lasts, and the writer thread's CPU time per sample (the put() side is a deque append on the reader's thread).
"""

from __future__ import annotations

import argparse
import gzip
import tempfile
import time
from pathlib import Path

from ahrsd.drivers.adis16405 import Adis16405
from ahrsd.drivers.rotating_log import LogLimits
from ahrsd.drivers.sample_log import GZIP_LEVEL, SampleLog
from ahrsd.drivers.simulated import SimulatedAdis16405

RATE_HZ = 819.2


def log_samples(samples, gzip_level: int, paced: bool = False) -> dict:
    n = len(samples)

    class LevelLog(SampleLog):
        pass

    LevelLog.gzip_level = gzip_level
    with tempfile.TemporaryDirectory() as d:
        cpu0 = time.thread_time()
        t0 = time.process_time()
        log = LevelLog(d, LogLimits(queue_entries=n + 1))
        t_put = time.perf_counter()
        if paced:
            burst = int(RATE_HZ * 0.05)
            due = time.monotonic()
            for i in range(0, n, burst):
                for s in samples[i:i + burst]:
                    log.put(s)
                due += burst / RATE_HZ
                time.sleep(max(0.0, due - time.monotonic()))
        else:
            for s in samples:
                log.put(s)
        put_s = time.perf_counter() - t_put
        log.close(timeout_s=600)
        writer_cpu_s = log.writer_cpu_s
        other_cpu_s = time.process_time() - t0 - (time.thread_time() - cpu0) - writer_cpu_s
        files = sorted(Path(d).glob("*.csv.gz"))
        gz_bytes = sum(p.stat().st_size for p in files)
        raw_bytes = sum(len(gzip.open(p).read()) for p in files)
    if other_cpu_s > 0.1 * writer_cpu_s + 0.05:
        print(f"  (note: {other_cpu_s:.2f} s of CPU in other threads of this process)")
    return {"written": log.written, "dropped": log.dropped, "gz_bytes": gz_bytes, "raw_bytes": raw_bytes,
            "writer_cpu_s": writer_cpu_s, "put_s": put_s}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=120.0, help="sensor seconds to log (default 120)")
    ap.add_argument("--scenario", default="level-turns", help="simulated scenario (default level-turns)")
    ap.add_argument("--levels", default=f"1,3,{GZIP_LEVEL},6,9", help="gzip levels to compare (comma-separated)")
    ap.add_argument("--paced", action="store_true", help="put the samples in real time at 819.2 SPS (50 ms bursts)")
    args = ap.parse_args()
    imu = Adis16405(SimulatedAdis16405(args.scenario, clock=None))
    imu.start()
    n = int(args.seconds * imu.sample_rate_hz)
    samples = [imu.read_sample() for _ in range(n)]
    print(f"{n} samples ({args.seconds:.0f} s of {args.scenario} at {imu.sample_rate_hz:.1f} SPS); "
          f"SampleLog's level is {GZIP_LEVEL}; {'paced at 819.2 SPS' if args.paced else 'in bulk'}")
    print("  level  B/sample  MB/h at 819.2 SPS  1 GB holds  plain CSV B/sample  writer µs/sample  % of a core"
          "  put() µs")
    for level in (int(v) for v in args.levels.split(",")):
        r = log_samples(samples, level, args.paced)
        if r["written"] != n:
            raise SystemExit(f"level {level}: written {r['written']} of {n} (dropped {r['dropped']})")
        per_hour = r["gz_bytes"] / n * RATE_HZ * 3600
        cpu_us = r["writer_cpu_s"] / n * 1e6
        print(f"  {level:5d}  {r['gz_bytes'] / n:8.1f}  {per_hour / 1e6:17.1f}  {1e9 / per_hour:8.1f} h"
              f"  {r['raw_bytes'] / n:17.1f}  {cpu_us:16.1f}  {cpu_us * RATE_HZ / 1e4:11.2f}"
              f"  {'—' if args.paced else format(r['put_s'] / n * 1e6, '.2f'):>8s}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
