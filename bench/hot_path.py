"""The daemon's per-sample path in process, without the sensor, the pipe or the event loop's waits: CPU time a
sample of `SampleReader.process` on blocks of 4 samples (what a poll tick takes from the reader process at
819.2 SPS) with a `Publishers.publish` after each block, for mekf and ins, with the simulated chip's magnetometer
calibration in force (as bench/latency.py runs the daemon). A hot loop: the daemon pays more per sample (its
caches are cold after every wake); use it to compare two versions of the code, bench/latency.py for the daemon.

    nice -n 10 .venv/bin/python bench/hot_path.py [--samples 8192] [--estimator mekf,ins] [--packed] [--block 4]

--packed: each block arrives packed, as from the reader process's pipe, and is unpacked inside the timed loop
(drivers.process_source: `unpack_block` where the code has it, else `unpack`), so the hand-over's unpacking is
counted too. --block N: N samples a block (the daemon's reader process hands over ~12 at its output deadlines,
docs/daemon.md "Performance").
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))          # the in-process service of the daemon tests (service_rig)
from bench.sim_calibration import save_mag_calibration, sim_chip_mag_model  # noqa: E402

RATE_HZ = 819.2
BLOCK = 4


def per_sample_us(estimator: str, n: int, packed: bool = False, block: int = BLOCK) -> float:
    """CPU µs a sample over n samples, after n samples of warm-up (initialisation, compilation)."""
    from service_rig import gcs_socket, start_service_on, stop_service

    from ahrsd.core.sample import ImuSample, SampleFlags
    from ahrsd.daemon.config import EndpointConfig, EstimatorConfig

    gcs = gcs_socket()
    rng = np.random.default_rng(1)
    samples = [ImuSample(k / RATE_HZ, rng.normal(0.0, 0.01, 3), np.array([0.1, 0.2, -9.81]) + rng.normal(0.0, 0.05, 3),
                         np.array([20.0, 3.0, 40.0]) + rng.normal(0.0, 0.3, 3), 25.0, 5.0, SampleFlags.NEW_DATA, 0, k)
               for k in range(2 * n)]
    blocks = [samples[k0:k0 + block] for k0 in range(0, 2 * n, block)]
    if packed:
        from ahrsd.drivers import process_source

        unpack = getattr(process_source, "unpack_block", process_source.unpack)
        data = [process_source.pack(b) for b in blocks]
        take = lambda i: unpack(data[i])                  # noqa: E731
    else:
        take = blocks.__getitem__
    block_n = block
    with tempfile.TemporaryDirectory() as tmp:
        save_mag_calibration(tmp, sim_chip_mag_model())
        service, loop = start_service_on((EndpointConfig(f"udpout:127.0.0.1:{gcs.getsockname()[1]}"),), tmp,
                                         estimator=EstimatorConfig(estimator))

        async def feed(lo: int, hi: int):
            for k0 in range(lo, hi, block_n):
                block = take(k0 // block_n)
                service.reader.process(block, block[-1].t_s)
                service.publishers.publish(block[-1].t_s)
                if k0 // block_n % 16 == 0:
                    try:
                        while True:
                            gcs.recv(65535)
                    except BlockingIOError:
                        pass

        try:
            loop.run_until_complete(feed(0, n))
            t0 = time.process_time()
            loop.run_until_complete(feed(n, 2 * n))
            return (time.process_time() - t0) / n * 1e6
        finally:
            stop_service(service, loop)
            gcs.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=8192)
    ap.add_argument("--estimator", default="mekf,ins")
    ap.add_argument("--packed", action="store_true", help="blocks unpacked from the reader process's records")
    ap.add_argument("--block", type=int, default=BLOCK, help="samples a block (default %(default)s)")
    args = ap.parse_args()
    n = args.samples // args.block * args.block
    for name in args.estimator.split(","):
        us = per_sample_us(name, n, args.packed, args.block)
        print(f"{name}: {us:.1f} µs of CPU a sample (reader.process + a publish every {args.block} samples), "
              f"{us * RATE_HZ / 1e4:.2f} % of a core at {RATE_HZ} SPS")


if __name__ == "__main__":
    main()
