"""Where a late wake's time goes, without Python: bench/wake_floor.py's loop (sleep to each sample time, 1/819.2 s
steps, CLOCK_MONOTONIC, SCHED_FIFO 50, memory locked) written in C, compiled here with `cc`, and for every wake
that slept and comes more than a quarter period late, the part of its lateness the thread spent runnable in the
kernel's run queue (the thread's run_delay, /proc/thread-self/schedstat, read after every wake; the catch-up wakes
after a blackout, whose targets were past before they slept, are counted but not split). The rest of the lateness
passed before the kernel woke the thread at all: the timer's interrupt came late (on a virtual machine the
virtual CPU was not running: the host ran something else; on hardware, interrupts were off that long). The
machine's steal time over the run (/proc/stat: time the hypervisor ran something else while a virtual CPU of
this machine wanted to run) is printed beside.

A wake later than one sample period is a sample an ADIS16405 reader loses (the chip holds a sample for one period
only); after a blackout of D s the loop's targets are past, so it counts about D/period late wakes, one per
sample lost. `events` counts the blackouts (late wakes after a sleep that really slept). `--both-cpus` runs a
loop on each of CPU 0 and CPU 1 in the same seconds and counts the blackouts that came on both at once (a
virtual machine's host takes one virtual CPU or the whole machine?).

    .venv/bin/python bench/wake_cause.py [--seconds 20] [--cpu N | --both-cpus] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

SOURCE = r"""
#define _GNU_SOURCE
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include <sched.h>
#include <sys/mman.h>
#include <sys/resource.h>
#include <fcntl.h>
#include <unistd.h>
#define MAX_LISTED 10000
static double due[MAX_LISTED], woke[MAX_LISTED];     /* each blackout's first late wake: due, woken (s) */
static double now(void) { struct timespec t; clock_gettime(CLOCK_MONOTONIC, &t); return t.tv_sec + t.tv_nsec * 1e-9; }
static double run_delay_s(int fd) {          /* schedstat: on-CPU ns, run-queue wait ns, timeslices */
    char b[128]; long long on_cpu = 0, wait = 0; ssize_t n = pread(fd, b, sizeof b - 1, 0);
    b[n > 0 ? n : 0] = 0; sscanf(b, "%lld %lld", &on_cpu, &wait); return wait * 1e-9; }
int main(int argc, char **argv) {
    double seconds = atof(argv[1]), period = 1.0 / 819.2;
    mlockall(MCL_CURRENT | MCL_FUTURE);
    struct sched_param sp = {.sched_priority = 50};
    int realtime = sched_setscheduler(0, SCHED_FIFO, &sp) == 0;
    int fd = open("/proc/thread-self/schedstat", O_RDONLY);
    long n = (long)(seconds / period), late = 0, late_quarter = 0, events = 0;
    double worst = 0, lag_sum = 0, queued_sum = 0, blackout_sum = 0, blackout_queued = 0, t_next = now() + period, rd_prev = run_delay_s(fd);
    struct timespec ts;
    for (long i = 0; i < n; i++) {
        double slept_from = now();
        ts.tv_sec = (time_t)t_next; ts.tv_nsec = (long)((t_next - ts.tv_sec) * 1e9);
        clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL);
        double lag = now() - t_next, rd = run_delay_s(fd), queued = rd - rd_prev;
        rd_prev = rd;
        int slept = slept_from < t_next;     /* a wake after a sleep, not a catch-up past targets already due */
        if (lag > 0.25 * period) {
            late_quarter++;
            if (slept) { lag_sum += lag; queued_sum += queued; }
            if (lag > period) {
                late++;
                if (slept) {
                    events++; blackout_sum += lag; blackout_queued += queued;
                    if (events <= MAX_LISTED) { due[events - 1] = t_next; woke[events - 1] = t_next + lag; }
                }
            }
        }
        if (lag > worst) worst = lag;
        t_next += period;
    }
    struct rusage ru;
    getrusage(RUSAGE_SELF, &ru);
    double cpu_s = ru.ru_utime.tv_sec + ru.ru_utime.tv_usec * 1e-6 + ru.ru_stime.tv_sec + ru.ru_stime.tv_usec * 1e-6;
    printf("{\"cpu_s\": %.4f, \"realtime\": %d, \"wakes\": %ld, \"late\": %ld, \"late_quarter\": %ld, \"events\": %ld, "
           "\"worst_s\": %.6f, \"slept_late_lag_s\": %.6f, \"slept_late_run_queue_s\": %.6f, \"blackouts_s\": %.6f, \"blackouts_run_queue_s\": %.6f}\n",
           cpu_s, realtime, n, late, late_quarter, events, worst, lag_sum, queued_sum, blackout_sum,
           blackout_queued);
    for (long i = 0; i < events && i < MAX_LISTED; i++) fprintf(stderr, "%.6f %.6f\n", due[i], woke[i]);
    return 0;
}
"""


def steal_s() -> float:
    """The machine's steal time so far, all CPUs (/proc/stat "cpu" line, 8th value, in USER_HZ ticks)."""
    with open("/proc/stat") as f:
        fields = f.readline().split()
    return int(fields[8]) / os.sysconf("SC_CLK_TCK")


def _compile(tmp: str) -> str:
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        raise SystemExit("bench/wake_cause.py needs a C compiler (cc)")
    src, exe = Path(tmp) / "wake_cause.c", Path(tmp) / "wake_cause"
    src.write_text(SOURCE)
    subprocess.run([cc, "-O2", "-o", str(exe), str(src)], check=True)
    return str(exe)


def _start(exe: str, seconds: float, cpu: int | None) -> subprocess.Popen:
    pin = None if cpu is None else (lambda: os.sched_setaffinity(0, {cpu}))
    return subprocess.Popen([exe, str(seconds)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=pin)


def _result(proc: subprocess.Popen) -> dict:
    """The loop's JSON, with its blackouts as (due, woken) CLOCK_MONOTONIC s pairs."""
    out, err = proc.communicate()
    if proc.returncode:
        raise RuntimeError(f"the C loop failed: {err}")
    r = json.loads(out)
    r["blackouts"] = [tuple(map(float, line.split())) for line in err.splitlines() if line.strip()]
    return r


def run_c_loop(seconds: float, cpu: int | None = None) -> dict:
    """Compile the loop and run it for `seconds` (on CPU `cpu` only, when given): its JSON, with the steal time
    and load average added."""
    with tempfile.TemporaryDirectory() as tmp:
        exe = _compile(tmp)
        load0, steal0 = os.getloadavg()[0], steal_s()
        out = _result(_start(exe, seconds, cpu))
    out.update(seconds=seconds, steal_s=steal_s() - steal0, load1_before=load0, load1_after=os.getloadavg()[0])
    return out


def overlapping(a: list[tuple[float, float]], b: list[tuple[float, float]]) -> int:
    """How many of the intervals `a` share time with one of `b` (each (start, end), sorted by start)."""
    return sum(shared_s([span], b) > 0.0 for span in a)


PERIOD_S = 1.0 / 819.2


def lost_s(blackouts: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The spans of sample times a reader woken by this loop would have lost: a wake due at t and woken after
    t + one period (a blackout from `due` to `woken` loses the samples due in [due, woken − period))."""
    return [(due, woken - PERIOD_S) for due, woken in blackouts if woken - PERIOD_S > due]


def shared_s(a: list[tuple[float, float]], b: list[tuple[float, float]]) -> float:
    """The total time the spans `a` and `b` (each sorted by start, none overlapping another of its own) share."""
    total, j = 0.0, 0
    for start, end in a:
        while j < len(b) and b[j][1] <= start:
            j += 1
        k = j
        while k < len(b) and b[k][0] < end:
            total += min(end, b[k][1]) - max(start, b[k][0])
            k += 1
    return total


def run_on_both_cpus(seconds: float) -> tuple[dict, dict, int]:
    """The loop on CPU 0 and on CPU 1 in the same seconds: both results and how many of CPU 0's blackouts (from
    the wake's due time to the time it woke) overlap one of CPU 1's. Few: the host takes one virtual CPU at a
    time, and a wake on the other would have come on time."""
    with tempfile.TemporaryDirectory() as tmp:
        exe = _compile(tmp)
        procs = [_start(exe, seconds, cpu) for cpu in (0, 1)]
        r0, r1 = (_result(p) for p in procs)
    return r0, r1, overlapping(r0["blackouts"], r1["blackouts"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--json", action="store_true", help="one JSON line")
    ap.add_argument("--cpu", type=int, default=None, help="run the loop on this CPU only (each virtual CPU apart)")
    ap.add_argument("--both-cpus", action="store_true",
                    help="a loop on CPU 0 and one on CPU 1 at once: do their blackouts come together?")
    args = ap.parse_args()
    if args.both_cpus:
        r0, r1, both = run_on_both_cpus(args.seconds)
        l0, l1 = lost_s(r0["blackouts"]), lost_s(r1["blackouts"])
        print(f"CPU 0: {r0['events']} blackouts (worst {r0['worst_s'] * 1e3:.1f} ms), CPU 1: {r1['events']} "
              f"(worst {r1['worst_s'] * 1e3:.1f} ms); {both} of CPU 0's overlap one of CPU 1's; load average "
              f"{os.getloadavg()[0]:.2f}")
        print(f"sample periods lost by a reader woken on CPU 0 {sum(e - s for s, e in l0) / PERIOD_S:.0f}, on CPU 1 "
              f"{sum(e - s for s, e in l1) / PERIOD_S:.0f}, on both (lost only when both were out) "
              f"{shared_s(l0, l1) / PERIOD_S:.0f}")
        return
    r = run_c_loop(args.seconds, args.cpu)
    if args.json:
        print(json.dumps({k: v for k, v in r.items() if k != "blackouts"}))
        return
    lag, queued = r["slept_late_lag_s"], r["slept_late_run_queue_s"]
    print(f"C loop, real-time {'yes' if r['realtime'] else 'NO'}: {r['wakes']} wakes in {args.seconds:g} s, "
          f"{r['late']} later than a period ({r['late'] / args.seconds:.2f}/s, in {r['events']} blackouts), "
          f"{r['late_quarter']} later than a quarter period, worst {r['worst_s'] * 1e3:.1f} ms; the blackouts' "
          f"first late wakes {r['blackouts_s'] * 1e3:.1f} ms late in all, of it {r['blackouts_run_queue_s'] * 1e3:.1f} ms "
          f"in the run queue; CPU {100 * r['cpu_s'] / args.seconds:.2f} % "
          f"of a core ({1e6 * r['cpu_s'] / r['wakes']:.1f} µs a wake)")
    print(f"  of the lateness of the wakes that slept and came more than a quarter period late ({lag * 1e3:.1f} ms in all), {queued * 1e3:.1f} ms "
          f"({100 * queued / max(lag, 1e-12):.1f} %) runnable in the run queue, the rest before the kernel woke "
          f"the thread; machine's steal time {r['steal_s'] * 1e3:.0f} ms ({100 * r['steal_s'] / args.seconds:.2f} % "
          f"of one CPU); load average {r['load1_before']:.2f} → {r['load1_after']:.2f}")


if __name__ == "__main__":
    main()
