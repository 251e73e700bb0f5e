"""What the GIL does to a sensor reader off the event loop: samples lost by the simulated chip (real-time clock,
819.2 SPS, no FIFO: a sample not read within 1.22 ms is gone) while the event loop in the main thread runs
Python code that holds the GIL — a handler busy for `--busy-ms` every `--every-ms` (a log flush, a GNSS burst,
a slow peer), plus a 200 Hz poll that takes the samples.

Readers compared, each `--seconds` long:
  loop          the chip read on the event loop (a timerfd deadline per sample, as daemon.sample_reader does)
  thread-5ms    drivers.threaded_source with the interpreter's default switch interval (5 ms)
  thread        drivers.threaded_source as shipped (switch interval SWITCH_INTERVAL_S)
  process       the same read loop in a child process (its own GIL); the busy loop in the parent

    nice -n 10 .venv/bin/python bench/reader_gil.py [--seconds 20] [--busy-ms 50] [--every-ms 200]

Lost = samples the chip produced that no read returned (the chip's own count, ground truth).
"""

from __future__ import annotations

import argparse
import asyncio
import multiprocessing
import os
import sys
import time


def busy(ms: float) -> None:
    end = time.perf_counter() + ms * 1e-3
    x = 0
    while time.perf_counter() < end:
        x += 1          # pure Python: holds the GIL between bytecodes


def open_chip():
    from ahrsd.drivers.simulated import SimulatedAdis16405
    from ahrsd.drivers.source import start_chip_source

    chip = SimulatedAdis16405("static", seed=1, clock=time.monotonic)
    src = start_chip_source(chip, "bench chip", clock=time.monotonic, self_test=False)
    return chip, src


async def load(seconds: float, busy_ms: float, every_ms: float, poll=None) -> int:
    loop = asyncio.get_running_loop()
    end = loop.time() + seconds
    next_busy = loop.time() + every_ms * 1e-3
    taken = 0
    while loop.time() < end:
        if poll is not None:
            taken += len(poll())
        if loop.time() >= next_busy:
            busy(busy_ms)
            next_busy += every_ms * 1e-3
        await asyncio.sleep(0.005)
    return taken


def run_loop(seconds, busy_ms, every_ms) -> dict:
    from ahrsd.daemon.timerfd import DeadlineTimer

    chip, src = open_chip()

    async def main():
        loop = asyncio.get_running_loop()

        def step():
            src.read_one(loop.time())
            t = src.next_read_time()
            timer.arm(t if t > loop.time() else loop.time())

        timer = DeadlineTimer(loop, step)
        timer.arm(loop.time())
        lost0 = chip.stats["samples_lost"]
        await load(seconds, busy_ms, every_ms)
        timer.close()
        return chip.stats["samples_lost"] - lost0

    lost = asyncio.run(main())
    return {"lost": lost, "produced": int(seconds * chip.sample_rate_hz)}


def run_thread(seconds, busy_ms, every_ms, switch_interval_s) -> dict:
    from ahrsd.drivers.threaded_source import ThreadedSource

    chip, src = open_chip()
    ts = ThreadedSource(src, switch_interval_s=switch_interval_s)
    ts.start()
    time.sleep(0.5)                                   # lock-in
    ts.poll()
    lost0 = chip.stats["samples_lost"]
    taken = asyncio.run(load(seconds, busy_ms, every_ms, ts.poll))
    lost = chip.stats["samples_lost"] - lost0
    ts.close()
    return {"lost": lost, "produced": int(seconds * chip.sample_rate_hz), "taken": taken,
            "rt": ts.stats["realtime_priority"]}


def _child(seconds: float, conn) -> None:
    from ahrsd.drivers.threaded_source import ThreadedSource

    chip, src = open_chip()
    ts = ThreadedSource(src)
    ts.start()
    time.sleep(0.5)
    ts.poll()
    conn.send("go")
    lost0 = chip.stats["samples_lost"]
    end = time.monotonic() + seconds
    taken = 0
    while time.monotonic() < end:
        taken += len(ts.poll())                       # the hand-over to the parent is not measured here
        time.sleep(0.005)
    conn.send({"lost": chip.stats["samples_lost"] - lost0, "produced": int(seconds * chip.sample_rate_hz),
               "taken": taken})
    ts.close()


def run_process(seconds, busy_ms, every_ms) -> dict:
    ctx = multiprocessing.get_context("spawn")
    parent, child = ctx.Pipe()
    p = ctx.Process(target=_child, args=(seconds, child))
    p.start()
    parent.recv()
    asyncio.run(load(seconds, busy_ms, every_ms))
    out = parent.recv()
    p.join(10)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--busy-ms", type=float, default=50.0)
    ap.add_argument("--every-ms", type=float, default=200.0)
    ap.add_argument("--readers", default="loop,thread-5ms,thread,process")
    args = ap.parse_args()
    from ahrsd.drivers.threaded_source import SWITCH_INTERVAL_S

    print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}; Python {sys.version.split()[0]}; "
          f"event loop busy {args.busy_ms:g} ms every {args.every_ms:g} ms, {args.seconds:g} s per reader")
    print("reader        lost / produced   lost %")
    for name in args.readers.split(","):
        if name == "loop":
            r = run_loop(args.seconds, args.busy_ms, args.every_ms)
        elif name == "thread-5ms":
            r = run_thread(args.seconds, args.busy_ms, args.every_ms, None)
        elif name == "thread":
            r = run_thread(args.seconds, args.busy_ms, args.every_ms, SWITCH_INTERVAL_S)
        elif name == "process":
            r = run_process(args.seconds, args.busy_ms, args.every_ms)
        else:
            raise SystemExit(f"no reader {name!r}")
        print(f"{name:12s} {r['lost']:6d} / {r['produced']:6d}   {100 * r['lost'] / r['produced']:6.2f}"
              + (f"   (SCHED_FIFO {'yes' if r.get('rt') else 'no'})" if "rt" in r else ""))


if __name__ == "__main__":
    main()
