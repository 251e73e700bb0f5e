"""The floor the operating system sets for any user-space reader of a chip without a FIFO: a bare loop that
sleeps to each sample time (1/819.2 s steps) at SCHED_FIFO 50 where allowed, alone in its process, and counts the
wakes that come more than one sample period late (each such wake would have lost at least one ADIS16405 sample,
which the chip holds for one period only). No ahrsd code runs: compare with bench/latency.py's spidev path.

    .venv/bin/python bench/wake_floor.py [--seconds 20] [--busy N] [--spin-us 100] [--json]

--json: one JSON line (wakes, late > a period, late > a quarter period, worst, CPU share): what bench/latency.py
--floor and bench/reader_floor.py run beside a reader, to compare the two in one run.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import time

PERIOD_S = 1.0 / 819.2


def _spin() -> None:
    while True:
        pass


def wake_lateness(seconds: float, spin_s: float = 0.0) -> tuple[bool, int, int, float, int, float]:
    """(real-time granted, wakes, wakes later than a period, worst lateness s, wakes later than a quarter
    period, CPU share of one core). spin_s: sleep until that long before each sample time, then spin to it."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(50))
        realtime = True
    except (PermissionError, OSError):
        realtime = False
    n = int(seconds / PERIOD_S)
    t_next = time.monotonic() + PERIOD_S
    late = late_quarter = 0
    worst = 0.0
    cpu0 = time.process_time()
    for _ in range(n):
        wait = t_next - spin_s - time.monotonic()
        if wait > 0.0:
            time.sleep(wait)
        while spin_s and time.monotonic() < t_next:
            pass
        lag = time.monotonic() - t_next
        late += lag > PERIOD_S
        late_quarter += lag > 0.25 * PERIOD_S
        worst = max(worst, lag)
        t_next += PERIOD_S
    return realtime, n, late, worst, late_quarter, (time.process_time() - cpu0) / seconds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--busy", type=int, default=0, help="busy-looping processes beside the loop")
    ap.add_argument("--json", action="store_true", help="one JSON line")
    ap.add_argument("--spin-us", type=float, default=0.0,
                    help="wake this long before each sample time and spin to it (does spinning help here?)")
    args = ap.parse_args()
    busy = [multiprocessing.Process(target=_spin, daemon=True) for _ in range(args.busy)]
    for p in busy:
        p.start()
    try:
        realtime, n, late, worst, late_quarter, cpu = wake_lateness(args.seconds, args.spin_us * 1e-6)
    finally:
        for p in busy:
            p.terminate()
    load1, load5, _ = os.getloadavg()
    if args.json:
        print(json.dumps({"realtime": realtime, "wakes": n, "late": late, "late_quarter": late_quarter,
                          "worst_s": worst, "cpu_share": cpu, "load1": load1}))
        return
    print(f"real-time {'yes' if realtime else 'NO'}, busy {args.busy}, spin {args.spin_us:g} µs: {n} wakes, {late} later "
          f"than a period ({late / args.seconds:.1f}/s), {late_quarter} later than a quarter period, worst "
          f"{worst * 1e3:.1f} ms, CPU {100 * cpu:.1f} % of a core; load average {load1:.2f} / {load5:.2f}")


if __name__ == "__main__":
    main()
