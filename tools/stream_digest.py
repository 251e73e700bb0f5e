"""An md5 digest of every MAVLink byte the daemon sends for a simulated recording: the check that making the event
loop's per-sample and per-output work cheaper leaves what it sends bit-identical.

    .venv/bin/python tools/stream_digest.py              # one line per run and one over all of them
    .venv/bin/python tools/stream_digest.py --seconds 20 # shorter runs (a quick look; the default is the check)

Run it in two checkouts (the same command in each worktree) and compare the lines. Each run is the in-process
service (tests/service_rig.py: the daemon's Service with a UDP endpoint, the `gcs` outputs and the `autopilot`
profile on a second endpoint) fed the simulated boat (seed 0, its chip's magnetometer errors calibrated, as
bench/latency.py runs the daemon) through the reader's hot path, `SampleReader.process`, in packed blocks as the
reader process hands them over (drivers.process_source `pack` → `unpack_block`), cut into blocks of 1 to 13
samples drawn from a seeded generator, each block followed by `Publishers.publish`, on a stepped clock (each
block's last sample time): no timer of the loop runs meanwhile, so the stream depends on the samples alone. Runs:
mekf and ins, each with the sensor mounted as the body (no mounting) and rotated (`mounting_rpy_deg`, the sensor-
frame path of the field calibration). Hashed: every datagram each endpoint received, in order, and the service's
counters (samples, late, published) at the end.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as _dt
import hashlib
import socket
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
for p in (REPO, REPO / "tests"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

RATE_HZ = 819.2
FIELD_DATE = _dt.date(2026, 12, 6)      # the WMM's date, as tools/estimate_digest.py (core.wmm.fixed_date)
RUNS = (("mekf", (0.0, 0.0, 0.0)), ("ins", (0.0, 0.0, 0.0)), ("mekf", (180.0, 0.0, 90.0)), ("ins", (180.0, 0.0, 90.0)))


def _drain(sock: socket.socket, h) -> int:
    """Every datagram waiting on `sock` into the hash, in order; how many."""
    n = 0
    while True:
        try:
            data = sock.recv(65535)
        except BlockingIOError:
            return n
        h.update(len(data).to_bytes(2, "little") + data)
        n += 1


def run_digest(estimator: str, mounting_rpy_deg: tuple, seconds: float) -> tuple[str, int]:
    """(the run's digest, datagrams received)."""
    from bench.sim_calibration import save_mag_calibration, sim_chip_mag_model
    from service_rig import start_service_on, stop_service

    from ahrsd.daemon.config import EndpointConfig, EstimatorConfig
    from ahrsd.drivers import process_source
    from ahrsd.simulation.stream import open_stream

    socks = []
    for _ in range(2):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        s.setblocking(False)
        socks.append(s)
    clock = [0.0]
    hashes = [hashlib.md5(), hashlib.md5()]
    received = 0
    stream = open_stream("boat", seed=0)
    rng = np.random.default_rng(7)
    with tempfile.TemporaryDirectory() as tmp:
        save_mag_calibration(tmp, sim_chip_mag_model("boat"))
        endpoints = (EndpointConfig(f"udpout:127.0.0.1:{socks[0].getsockname()[1]}"),
                     EndpointConfig(f"udpout:127.0.0.1:{socks[1].getsockname()[1]}", profile="autopilot"))
        service, loop = start_service_on(endpoints, tmp, clock=lambda: clock[0], warm_fit_worker=False,
                                         estimator=EstimatorConfig(estimator))
        service.pipeline.set_mounting(mounting_rpy_deg)
        rotation = service.pipeline.mounting

        async def feed() -> int:
            """The whole run without a wait: no timer of the loop runs in between."""
            n_total, n, counter, got = int(seconds * RATE_HZ), 0, 0, 0
            while n < n_total:
                k = int(min(rng.integers(1, 14), n_total - n))
                samples = stream.next_block(k).samples(first_counter=counter)
                if rotation is not None:      # the chip is mounted rotated: it measures in its own axes
                    samples = [dataclasses.replace(s, gyro_rad_s=rotation.T @ s.gyro_rad_s,
                                                   accel_m_s2=rotation.T @ s.accel_m_s2,
                                                   mag_ut=rotation.T @ s.mag_ut) for s in samples]
                counter += k
                n += k
                block = process_source.unpack_block(process_source.pack(samples))
                now = float(block.t_s[-1])
                clock[0] = now
                service.reader.process(block, now)
                service.publishers.publish(now)
                got += sum(_drain(sock, h) for sock, h in zip(socks, hashes))
            return got

        try:
            received = loop.run_until_complete(feed())
            c = service.counters
            tail = f"{service.pipeline.counters.samples} {c.late_samples} {c.published}".encode()
        finally:
            stop_service(service, loop)
            for s in socks:
                s.close()
    total = hashlib.md5()
    for h in hashes:
        total.update(h.digest())
    total.update(tail)
    return total.hexdigest(), received


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    args = ap.parse_args()
    from ahrsd.core import wmm

    everything = hashlib.md5()
    with wmm.fixed_date(FIELD_DATE):
        for estimator, rpy in RUNS:
            digest, n = run_digest(estimator, rpy, args.seconds)
            print(f"{estimator} mounting {rpy}: {digest} ({n} datagrams)", flush=True)
            everything.update(digest.encode())
    print(f"all {everything.hexdigest()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
