"""Why a spidev reader loses samples: how late each read starts after the moment the reader meant to read
(its SampleTimer's target, 50 µs after the predicted data-ready), per reader set-up, as a histogram in sample
periods. The ADIS16405 keeps a sample for one period (1.22 ms at 819.2 SPS): a read that starts more than about
a period late has lost the sample before it (the chip's own count, ground truth, is printed beside).

Set-ups, each `--seconds` long, in this process (the simulated chip on the real-time clock, self-test skipped):
  alone            drivers.threaded_source's reader thread with nothing else in the process but the simulated
                   chip (whose block producer — the simulator's numpy/Python work that the real chip does in
                   silicon — runs in a helper thread of the same process, drivers.simulated._next_block)
  alone-precomp    the same, the chip's blocks computed before the run (no producer work while reading): what
                   the OS scheduler alone gives the reader
  alone-producer   the same, the chip's blocks computed in a process of its own (drivers.sim_block_producer)
  daemon[-producer] the reader thread inside a running daemon (daemon.service.Service, autopilot profile, mekf):
                   the event loop and the chip's producer share the reader's GIL
  daemon-5ms       the same with the interpreter's default switch interval (5 ms) instead of SWITCH_INTERVAL_S
  *-nort           (with --no-rt-too) the same without SCHED_FIFO

    nice -n 10 .venv/bin/python bench/reader_lateness.py [--seconds 20] [--setups alone,alone-precomp,daemon]
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import os
import socket
import sys
import tempfile
import time

import numpy as np

BINS = (0.0, 0.25, 0.5, 1.0, 2.0, 5.0, np.inf)      # in sample periods


class PrecomputedStream:
    """A simulation stream whose blocks were computed before the run (next_block is a slice)."""

    def __init__(self, stream, seconds: float, rate_hz: float, block: int = 256):
        n = int(seconds * rate_hz / block) + 4
        self.blocks = [stream.next_block(block) for _ in range(n)]
        self.i = 0

    def next_block(self, n):
        blk = self.blocks[self.i % len(self.blocks)]
        self.i += 1
        return blk


def instrument(src, late: list, lost: list):
    """Record, per read, clock() at the read − the target the reader slept until (seconds)."""
    inner = src.inner                              # GroundTruthSource → ReconnectingSource → ChipSource
    target = [0.0]
    next_read_time, read_one = inner.next_read_time, inner.read_one

    def nrt():
        target[0] = next_read_time()
        return target[0]

    def r1(now):
        if target[0] > 0.0:
            late.append(time.monotonic() - target[0])
        s = read_one(now)
        if s is not None and int(s.flags) & 0x4:     # GAP_BEFORE: the timer counted samples lost before it
            lost.append(len(late) - 1)
        return s

    inner.next_read_time, inner.read_one = nrt, r1


def open_reader(precomputed: float, realtime: bool, switch_s, producer: str = "thread"):
    from ahrsd.drivers.ground_truth import BurstIndexTap, GroundTruthSource
    from ahrsd.drivers.reconnecting import ReconnectingSource
    from ahrsd.drivers.simulated import SimulatedAdis16405
    from ahrsd.drivers.source import open_chip_driver
    from ahrsd.drivers.threaded_source import ThreadedSource
    from ahrsd.simulation import open_stream

    scenario = "static"
    if precomputed:
        scenario = PrecomputedStream(open_stream("static", rate_hz=819.2, seed=1, errors="adis16405", start_s=0.0),
                                     precomputed, 819.2)
    chip = SimulatedAdis16405(scenario, seed=1, clock=time.monotonic, producer=producer)
    tap = BurstIndexTap(chip)
    src = GroundTruthSource(ReconnectingSource(lambda: tap, open_chip_driver, "bench chip", reopen_same_bus=True),
                            chip, tap)
    src.start()
    return chip, ThreadedSource(src, realtime=realtime, switch_interval_s=switch_s)


def run(setup: str, seconds: float) -> dict:
    from ahrsd.drivers.threaded_source import SWITCH_INTERVAL_S

    realtime = not setup.endswith("-nort")
    base = setup.removesuffix("-nort")
    switch_s = None if base == "daemon-5ms" else SWITCH_INTERVAL_S
    chip, reader = open_reader(seconds + 5 if base == "alone-precomp" else 0.0, realtime, switch_s,
                               "process" if base.endswith("-producer") else "thread")
    late: list[float] = []
    lost: list[int] = []
    instrument(reader, late, lost)
    lost0 = None
    if base.startswith("alone"):
        reader.start()
        time.sleep(1.0)
        lost0, n0 = chip.stats["samples_lost"], len(late)
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            reader.poll()
            time.sleep(0.005)
        lost1 = chip.stats["samples_lost"]
        reader.close()
    else:
        from ahrsd.daemon.config import Config, EndpointConfig, StateConfig
        from ahrsd.daemon.service import Service

        sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sink.bind(("127.0.0.1", 0))
        with tempfile.TemporaryDirectory() as tmp:
            cfg = dataclasses.replace(Config(), endpoints=(EndpointConfig(
                f"udpout:127.0.0.1:{sink.getsockname()[1]}", profile="autopilot"),), state=StateConfig(tmp))
            service = Service(cfg, source=reader)

            async def main():
                nonlocal lost0, n0, lost1
                task = asyncio.create_task(service.run())
                await asyncio.sleep(3.0)
                lost0, n0 = chip.stats["samples_lost"], len(late)
                await asyncio.sleep(seconds)
                lost1 = chip.stats["samples_lost"]
                service.request_stop()
                await task

            n0 = lost1 = 0
            asyncio.run(main())
        sink.close()
    period = 1.0 / chip.sample_rate_hz
    x = np.array(late[n0:]) / period
    hist, _ = np.histogram(x, bins=BINS)
    return {"hist": hist, "reads": len(x), "lost_truth": lost1 - lost0, "p99": np.percentile(x, 99) if len(x) else 0,
            "max": x.max() if len(x) else 0, "produced": int(seconds * chip.sample_rate_hz)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--setups", default="alone,alone-precomp,alone-producer,daemon,daemon-producer,daemon-5ms")
    ap.add_argument("--no-rt-too", action="store_true", help="each set-up also without SCHED_FIFO")
    args = ap.parse_args()
    setups = args.setups.split(",")
    if args.no_rt_too:
        setups += [s + "-nort" for s in setups]
    load0 = os.getloadavg()[0]
    results = {s: run(s, args.seconds) for s in setups}
    print(f"machine: {os.cpu_count()} CPUs, load average {load0:.2f} → {os.getloadavg()[0]:.2f} (shared machine); "
          f"Python {sys.version.split()[0]}, {args.seconds:g} s per set-up")
    edges = " ".join(f"<{b:g}P" if np.isfinite(b) else f"≥{BINS[-2]:g}P" for b in BINS[1:])
    print(f"read start − target, in sample periods P (share of reads): {edges}")
    print(f"{'set-up':17s} {'reads':>7s} " + " ".join(f"{e:>7s}" for e in edges.split()) +
          f" {'p99 P':>7s} {'max P':>7s} {'lost (chip)':>12s}")
    for s, r in results.items():
        share = r["hist"] / max(1, r["reads"])
        print(f"{s:17s} {r['reads']:7d} " + " ".join(f"{100 * v:6.2f}%" for v in share) +
              f" {r['p99']:7.2f} {r['max']:7.1f} {r['lost_truth']:6d} ({100 * r['lost_truth'] / r['produced']:.3f} %)")


if __name__ == "__main__":
    main()
