"""The floor the operating system sets for any user-space reader of a chip without a FIFO: a bare loop that
sleeps to each sample time (1/819.2 s steps) at SCHED_FIFO 50 where allowed, alone in its process, and counts the
wakes that come more than one sample period late (each such wake would have lost at least one ADIS16405 sample,
which the chip holds for one period only). No ahrsd code runs: compare with bench/latency.py's spidev path.

    .venv/bin/python bench/wake_floor.py [--seconds 20] [--busy N] [--spin-us 100] [--json]
    .venv/bin/python bench/wake_floor.py --compiled [--seconds 20]    # the same loop in C (the system's cc)

--json: one JSON line (wakes, late > a period, late > a quarter period, worst, CPU share): what bench/latency.py
--floor and bench/reader_floor.py run beside a reader, to compare the two in one run.

--compiled: the same loop as a C program (clock_nanosleep to each absolute sample time, SCHED_FIFO 50 where
allowed), built with the system's `cc` into a temporary directory: the CPU a wake costs with no interpreter at all
(the kernel's sleep, timer and context switches on this machine), against the Python loop's. Its CPU share is the
program's own CPU clock (CLOCK_PROCESS_CPUTIME_ID), as the Python loop's (time.process_time). What a reader step
written in C would pay per sample at the least (docs/daemon.md "Session 42 (spicpu)").
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import shutil
import subprocess
import tempfile
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


# The loop of wake_lateness in C: the same absolute sample times (PERIOD_S steps from one period after the start),
# the same lateness counts, one JSON line like --json's. argv: wakes, period in ns.
C_LOOP = r"""
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

static double now_s(clockid_t clock) {
    struct timespec t;
    clock_gettime(clock, &t);
    return t.tv_sec + t.tv_nsec * 1e-9;
}

int main(int argc, char **argv) {
    long n = atol(argv[1]);
    long long period_ns = atoll(argv[2]);
    struct sched_param sp = {.sched_priority = 50};
    int realtime = sched_setscheduler(0, SCHED_FIFO, &sp) == 0;
    struct timespec next;
    clock_gettime(CLOCK_MONOTONIC, &next);
    long long next_ns = next.tv_sec * 1000000000LL + next.tv_nsec + period_ns;
    long late = 0, late_quarter = 0;
    double worst = 0.0, cpu0 = now_s(CLOCK_PROCESS_CPUTIME_ID), wall0 = now_s(CLOCK_MONOTONIC);
    for (long k = 0; k < n; k++) {
        next.tv_sec = next_ns / 1000000000LL;
        next.tv_nsec = next_ns % 1000000000LL;
        while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next, NULL) != 0) {
        }
        double lag = now_s(CLOCK_MONOTONIC) - next_ns * 1e-9;
        late += lag > period_ns * 1e-9;
        late_quarter += lag > 0.25 * period_ns * 1e-9;
        if (lag > worst) worst = lag;
        next_ns += period_ns;
    }
    double cpu = now_s(CLOCK_PROCESS_CPUTIME_ID) - cpu0, wall = now_s(CLOCK_MONOTONIC) - wall0;
    printf("{\"realtime\": %s, \"wakes\": %ld, \"late\": %ld, \"late_quarter\": %ld, \"worst_s\": %.9f, "
           "\"cpu_s\": %.9f, \"wall_s\": %.9f}\n", realtime ? "true" : "false", n, late, late_quarter, worst, cpu,
           wall);
    return 0;
}
"""


def compiled_wake_lateness(seconds: float, period_s: float = PERIOD_S, cc: str | None = None) -> dict:
    """wake_lateness's loop in C (C_LOOP, built with `cc`, default the system's): its JSON line as a dict, plus
    `cpu_share` (the program's CPU over `seconds`). Raises FileNotFoundError when there is no C compiler."""
    cc = cc or shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        raise FileNotFoundError("no C compiler (cc) for --compiled")
    with tempfile.TemporaryDirectory(prefix="wake_floor_") as tmp:
        src, exe = os.path.join(tmp, "loop.c"), os.path.join(tmp, "loop")
        with open(src, "w") as f:
            f.write(C_LOOP)
        subprocess.run([cc, "-O2", "-o", exe, src], check=True)
        n = int(seconds / period_s)
        out = subprocess.run([exe, str(n), str(round(period_s * 1e9))], check=True, capture_output=True, text=True)
    result = json.loads(out.stdout)
    result["cpu_share"] = result["cpu_s"] / seconds
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--busy", type=int, default=0, help="busy-looping processes beside the loop")
    ap.add_argument("--json", action="store_true", help="one JSON line")
    ap.add_argument("--spin-us", type=float, default=0.0,
                    help="wake this long before each sample time and spin to it (does spinning help here?)")
    ap.add_argument("--compiled", action="store_true",
                    help="the same loop in C, built with the system's cc: the CPU a wake costs without Python")
    args = ap.parse_args()
    if args.compiled:
        r = compiled_wake_lateness(args.seconds)
        load1, load5, _ = os.getloadavg()
        if args.json:
            print(json.dumps({**r, "load1": load1}))
            return
        print(f"C loop: real-time {'yes' if r['realtime'] else 'NO'}: {r['wakes']} wakes, {r['late']} later than a "
              f"period, {r['late_quarter']} later than a quarter period, worst {r['worst_s'] * 1e3:.1f} ms, CPU "
              f"{100 * r['cpu_share']:.2f} % of a core ({1e6 * r['cpu_s'] / r['wakes']:.1f} µs a wake); load average "
              f"{load1:.2f} / {load5:.2f}")
        return
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
          f"{worst * 1e3:.1f} ms, CPU {100 * cpu:.1f} % of a core ({1e6 * cpu * args.seconds / n:.1f} µs a wake); "
          f"load average {load1:.2f} / {load5:.2f}")


if __name__ == "__main__":
    main()
