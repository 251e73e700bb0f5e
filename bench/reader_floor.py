"""The spidev reader process against the machine's floor, in one run: drivers.process_source's reader (the
simulated ADIS16405 at 819.2 SPS, the daemon's default path, without the daemon) and bench/wake_floor.py's bare
SCHED_FIFO loop and bench/wake_cause.py's C loop run side by side for `--seconds`; a reader that is at the floor
loses about one chip sample for each of the bare loops' wakes later than a period (a loop catches up after a
blackout with one late wake per period it missed; the reader wakes once, for the next sample, and counts one
late wake). This process plays the daemon: it polls the reader every 5 ms, and with `--stall-s X` stops polling for X s
every `--stall-every` s (a stalled daemon: its reader must read on, its hand-over queue).

    .venv/bin/python bench/reader_floor.py [--seconds 60] [--stall-s 2 --stall-every 10] [--busy N]

Prints, per loop: wakes later than a quarter period and than a period (a wake later than a period loses a
chip sample), per second; the worst; for the reader also the chip's own count of the samples it lost (ground
truth), the longest read, the longest hand-over tick, the garbage collector's pauses, and the CPU share of one
core of the reader process (utime + stime / wall); the load average before and after.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

REPO = Path(__file__).resolve().parents[1]


def _cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--stall-s", type=float, default=0.0, help="stop polling the reader for this long ...")
    ap.add_argument("--stall-every", type=float, default=10.0, help="... every this many seconds")
    ap.add_argument("--busy", type=int, default=0, help="busy-looping processes beside both")
    args = ap.parse_args()

    from ahrsd.daemon.config import SensorConfig
    from ahrsd.drivers.process_source import ProcessSource

    load0 = os.getloadavg()[0]
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.busy)]
    src = ProcessSource(SensorConfig(source="sim", reader="process"))
    try:
        src.poll()                                           # "go": the reader starts
        time.sleep(1.0)
        src.poll()
        c0 = dict(src.counters())
        cpu0, wall0 = _cpu_s(src._proc.pid), time.monotonic()
        floor = subprocess.Popen([sys.executable, str(REPO / "bench" / "wake_floor.py"), "--seconds",
                                  str(args.seconds), "--json"], stdout=subprocess.PIPE, text=True)
        c_floor = subprocess.Popen([sys.executable, str(REPO / "bench" / "wake_cause.py"), "--seconds",
                                    str(args.seconds), "--json"], stdout=subprocess.PIPE, text=True)
        end = wall0 + args.seconds
        next_stall = wall0 + args.stall_every if args.stall_s > 0 else float("inf")
        received = 0
        while time.monotonic() < end:
            received += len(src.poll())
            if time.monotonic() >= next_stall:
                time.sleep(args.stall_s)
                next_stall += args.stall_every
            time.sleep(0.005)
        floor_out = json.loads(floor.communicate()[0])
        c_out = json.loads(c_floor.communicate()[0])
        time.sleep(0.5)                                      # the reader's last counters
        received += len(src.poll())
        cpu1, wall1 = _cpu_s(src._proc.pid), time.monotonic()
        c1 = src.counters()
    finally:
        src.close()
        for p in busy:
            p.kill()
            p.wait()

    def d(key: str) -> int:
        return c1.get(key, 0) - c0.get(key, 0)

    secs = wall1 - wall0
    lost = d("sensor_lost_outside_faults")
    produced = d("handover_sent") + lost
    print(f"machine: {os.cpu_count()} CPUs, load average {load0:.2f} → {os.getloadavg()[0]:.2f}; {args.seconds:g} s"
          f"{f', busy {args.busy}' if args.busy else ''}"
          f"{f', the poller stalls {args.stall_s:g} s every {args.stall_every:g} s' if args.stall_s else ''}")
    fl = floor_out
    print(f"wake_floor    real-time {'yes' if fl['realtime'] else 'NO'}: late > P/4 {fl['late_quarter'] / args.seconds:6.2f}/s,"
          f" > P {fl['late'] / args.seconds:6.2f}/s, worst {fl['worst_s'] * 1e3:6.1f} ms, CPU {100 * fl['cpu_share']:.1f} %")
    c = c_out
    print(f"wake_cause C  real-time {'yes' if c['realtime'] else 'NO'}: late > P/4 {c['late_quarter'] / args.seconds:6.2f}/s,"
          f" > P {c['late'] / args.seconds:6.2f}/s, worst {c['worst_s'] * 1e3:6.1f} ms, in {c['events']} blackouts; "
          f"{100 * c['slept_late_run_queue_s'] / max(c['slept_late_lag_s'], 1e-12):.1f} % of the lateness runnable "
          f"in the run queue; steal {c['steal_s'] * 1e3:.0f} ms")
    print(f"reader proc.  real-time {'yes' if c1.get('reader_realtime_priority') else 'NO'}: late > P/4 "
          f"{d('reader_wakes_late_quarter') / secs:6.2f}/s, > P {d('reader_wakes_late') / secs:6.2f}/s, worst "
          f"{c1.get('reader_wake_late_max_us', 0) / 1e3:6.1f} ms (whole run), CPU {100 * (cpu1 - cpu0) / secs:.1f} %")
    print(f"  chip samples lost (truth) {lost} of {produced} ({100 * lost / max(1, produced):.3f} %, "
          f"{lost / secs:.2f}/s); hand-over dropped {d('reader_handover_dropped')}; longest read "
          f"{c1.get('reader_read_us_max', 0)} µs, hand-over tick {c1.get('handover_work_us_max', 0)} µs; GC "
          f"{d('reader_gc_collections')} collections (longest {c1.get('reader_gc_pause_max_us', 0)} µs); "
          f"producer waits {d('sensor_producer_waits')}")
    # a floor loop catches up after a blackout with one late wake per sample period it missed (each a sample lost
    # by a reader of the chip), the reader wakes once for the next sample: compare its losses with their count
    def ratio(floor_late: int) -> str:
        return f"{(lost / secs) / (floor_late / args.seconds):.2f}" if floor_late else "— (the floor lost none)"

    print(f"chip samples lost by the reader / floor wakes later than a period: python {ratio(fl['late'])}, "
          f"C {ratio(c['late'])}")


if __name__ == "__main__":
    main()
