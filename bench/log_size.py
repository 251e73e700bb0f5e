"""The on-vehicle sample log's disk rate and writer cost: samples from the simulated ADIS16405 through the real
driver (quantised and scaled as on the vehicle) at 819.2 SPS, logged by SampleLog as .csv.gz.

    .venv/bin/python bench/log_size.py [--seconds 120] [--scenario level-turns]

Prints the compressed and uncompressed bytes per sample, MB per hour at 819.2 SPS, how long 1 GB lasts, and
the writer thread's CPU time per sample (the put() side is a queue append on the reader's thread).
"""

from __future__ import annotations

import argparse
import gzip
import tempfile
import time
from pathlib import Path

from ahrsd.drivers.adis16405 import Adis16405
from ahrsd.drivers.rotating_log import LogLimits
from ahrsd.drivers.sample_log import SampleLog
from ahrsd.drivers.simulated import SimulatedAdis16405

RATE_HZ = 819.2


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=120.0, help="sensor seconds to log (default 120)")
    ap.add_argument("--scenario", default="level-turns", help="simulated scenario (default level-turns)")
    args = ap.parse_args()
    imu = Adis16405(SimulatedAdis16405(args.scenario, clock=None))
    imu.start()
    n = int(args.seconds * imu.sample_rate_hz)
    samples = [imu.read_sample() for _ in range(n)]
    with tempfile.TemporaryDirectory() as d:
        cpu0 = time.thread_time()
        t0 = time.process_time()
        log = SampleLog(d, LogLimits(queue_entries=n + 1))
        t_put = time.perf_counter()
        for s in samples:
            log.put(s)
        put_s = time.perf_counter() - t_put
        log.close(timeout_s=600)
        writer_cpu_s = time.process_time() - t0 - (time.thread_time() - cpu0)
        files = sorted(Path(d).glob("*.csv.gz"))
        gz_bytes = sum(p.stat().st_size for p in files)
        raw_bytes = sum(len(gzip.open(p).read()) for p in files)
    per_hour = gz_bytes / n * RATE_HZ * 3600
    print(f"{n} samples ({args.seconds:.0f} s of {args.scenario} at {imu.sample_rate_hz:.1f} SPS), "
          f"written {log.written}, dropped {log.dropped}")
    print(f"  compressed {gz_bytes / n:.1f} B/sample, uncompressed {raw_bytes / n:.1f} B/sample "
          f"(ratio {raw_bytes / gz_bytes:.2f})")
    print(f"  at 819.2 SPS: {per_hour / 1e6:.1f} MB/h compressed ({raw_bytes / n * RATE_HZ * 3600 / 1e6:.0f} MB/h "
          f"as plain CSV); 1 GB holds {1e9 / per_hour:.1f} h")
    print(f"  writer thread CPU {writer_cpu_s / n * 1e6:.1f} µs/sample = {writer_cpu_s / n * RATE_HZ * 100:.1f} % of "
          f"one core at 819.2 SPS; put() {put_s / n * 1e6:.2f} µs/sample on the caller's thread")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
