"""The reader process's cost per read, counted: drivers.process_source's reader (the simulated ADIS16405 at 819.2
SPS, the daemon's default path) against this process playing the daemon (it takes each block when the pipe becomes
readable and asks for the next one `--hz` times a second, as the daemon's output deadlines do: 70 a second with the
`gcs` outputs, 60 with `autopilot`).

    .venv/bin/python bench/reader_calls.py [--seconds 20] [--hz 70] [--profile]
    .venv/bin/python bench/reader_calls.py --numpy-block 12    # batching the decode with numpy, in a hot loop
    .venv/bin/python bench/reader_calls.py --compiled-decode   # the burst decode in numba against Python, hot loop
    .venv/bin/python bench/reader_calls.py --split             # + the reader's CPU from a wake to the next wait
    .venv/bin/python bench/reader_calls.py --hot 20000         # the same per-read step with no sleep (caches kept)
    .venv/bin/python bench/reader_calls.py --split --bound     # the common read without its decode: a bound
    .venv/bin/python bench/reader_calls.py --seconds 5 --import-numba   # the reader's start with numba imported
    .venv/bin/python bench/reader_calls.py --split --compiled-read     # the frame's decode in numba, after real sleeps

Prints, over the window (after a 4 s warm-up): the reads a second, the reader thread's CPU (user, system, and the
scheduler's run time from /proc/PID/task/TID/schedstat) as a share of a core and per read, and the simulated chip's
part of it (its register model and truth bookkeeping, `sensor_simulated_cpu_s`: not there on hardware). With
`--profile` the reader thread runs under cProfile and the bench prints the Python calls a read (a count: the same
on any machine) and the profiled time a read by part of the path (driver, timer, reader loop, hand-over, the
simulated chip); the profiler's own cost inflates that time, so compare parts and counts, not the total.
"""

from __future__ import annotations

import argparse
import importlib
import math
import os
import select
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

PARTS = (      # (part, the files whose Python it is)
    ("simulated chip", ("simulated.py", "sim_clock.py", "sim_block_stream.py", "faults.py", "ground_truth.py")),
    ("driver (adis16405)", ("adis16405.py",)),
    ("timer (sample_timer, chip_source)", ("sample_timer.py", "chip_source.py")),
    ("reader loop and pacing", ("threaded_source.py", "reconnecting.py", "read_failures.py", "threading.py")),
    ("hand-over", ("process_source.py", "sample_record.py", "sharedctypes.py")),
)


def child(*args, **kwargs):
    """The reader process's entry (drivers.process_source._child), its reader thread under cProfile when
    READER_CALLS_PROFILE names the file to write."""
    from ahrsd.drivers import process_source, threaded_source

    if os.environ.get("READER_CALLS_SPLIT"):
        time_loop_work(threaded_source._Pacing)
    if os.environ.get("READER_CALLS_BOUND"):
        bound_common_read()
    if os.environ.get("READER_CALLS_COMPILED"):
        compiled_common_read()
    if os.environ.get("READER_CALLS_IMPORT_NUMBA"):
        importlib.import_module("numba")      # what a numba kernel in the reader would cost its start
    out = os.environ.get("READER_CALLS_PROFILE")
    if out:
        import cProfile

        run = threaded_source.ThreadedSource._run

        def profiled_run(self):
            profiler = cProfile.Profile()
            profiler.enable()
            try:
                run(self)
            finally:
                profiler.disable()
                profiler.dump_stats(out)

        threaded_source.ThreadedSource._run = profiled_run
    return process_source._child(*args, **kwargs)


def time_loop_work(pacing_class, cpu_ns=time.thread_time_ns) -> None:
    """Count the reader thread's CPU between two waits (`wait_for_sample` of drivers.threaded_source._Pacing): the
    per-read work from the wake's return to the next sleep (the read, the simulated chip, the hand-over tick), into
    the reader's stats (`split_work_ns`, `split_loops`, reported as reader_ counters). The wait itself (the timer's
    next read time, the sleep's system call and context switches) is left out."""
    wait = pacing_class.wait_for_sample

    def timed_wait(self):
        entered = cpu_ns()
        left = getattr(self, "_split_left_ns", None)
        if left is not None:
            self.stats["split_work_ns"] = self.stats.get("split_work_ns", 0) + entered - left
            self.stats["split_loops"] = self.stats.get("split_loops", 0) + 1
        try:
            return wait(self)
        finally:
            self._split_left_ns = cpu_ns()

    pacing_class.wait_for_sample = timed_wait


def bound_common_read() -> None:
    """The reader's common read (drivers.chip_source.ChipSource.read_one) cut to the burst transfer, the timer's
    step and a record made once: no unpacking, checks, sign extension, stuck-axis check or scaling. Not a reader
    (the frame is not looked at): the bound on what any faster decode of the frame (compiled, batched) could take
    off a read after a real sleep, the loop, the wake, the timer and the hand-over left as they are."""
    from ahrsd.core.sample import SampleFlags
    from ahrsd.drivers import chip_source
    from ahrsd.drivers.sample_record import SampleRecord

    read_one = chip_source.ChipSource.read_one
    values = (0.0,) * 11          # the nine axes, temp_c, supply_v
    new_data, gap = int(SampleFlags.NEW_DATA), int(SampleFlags.GAP_BEFORE)

    def bounded(self, now: float):
        timer, driver = self.timer, self.driver
        if not (driver.samples_as_records and self._common_timer and timer.hi is not None):
            return read_one(self, now)
        now = max(now, self.clock())
        driver.read_burst()
        t_s, k, lost = timer.fresh_after_first(now, self.clock(), False)
        return SampleRecord((t_s, *values, new_data | (gap if lost else 0), 0, k))

    chip_source.ChipSource.read_one = bounded


def compiled_common_read() -> None:
    """The reader's common read with the frame's Python (unpacking, the ND/EA and supply checks, the nine sign
    extensions, the burst-bug and full-scale bounds, the stuck-axis runs, the nine products, temperature and supply)
    in one numba call, the transfer, the timer's step and the record's tuple left in Python: what a compiled decode
    saves after a real sleep, against `--bound` (none of that work) and the reader as it is. Not a reader: the
    stuck-axis runs are the kernel's own (never flagged), a frame the kernel refuses goes to the general path."""
    import numba
    import numpy as np

    from ahrsd.core.sample import SampleFlags
    from ahrsd.drivers import chip_source
    from ahrsd.drivers import registers as R
    from ahrsd.drivers.sample_record import SampleRecord

    @numba.njit(cache=False)
    def decode(rx, full9, scale9, prev9, runs9, gyro_range, jump, prev_gx, supply_min, supply_max):
        w = np.empty(12, np.int64)
        for i in range(12):
            w[i] = (np.int64(rx[2 + 2 * i]) << 8) | np.int64(rx[3 + 2 * i])
        both, either = 0xC000, 0
        for i in range(10):
            both &= w[i]
            either |= w[i]
        supply = w[0] & 0x3FFF
        nothing = (1, 0, 0, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        if both != 0x8000 or either & 0x4000 or supply < supply_min or supply > supply_max:
            return nothing
        gx = ((w[1] & 0x3FFF) ^ 0x2000) - 0x2000
        if not (w[1] & 0x2000) and (gx > gyro_range or gx - prev_gx > jump):
            return nothing
        v = np.empty(9)
        run_max = 0
        for i in range(9):
            r = ((w[i + 1] & 0x3FFF) ^ 0x2000) - 0x2000
            if abs(r) >= full9[i]:
                return nothing
            if r == prev9[i]:
                runs9[i] += 1
            else:
                runs9[i] = 0
                prev9[i] = r
            run_max = max(run_max, runs9[i])
            v[i] = r * scale9[i]
        temp_c = R_TEMP_AT_ZERO + R_TEMP_PER_LSB * (((w[10] & 0x0FFF) ^ 0x0800) - 0x0800)
        return (0, gx, supply, run_max, v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7], v[8], temp_c,
                supply * R_SUPPLY_V_PER_LSB)

    R_TEMP_AT_ZERO, R_TEMP_PER_LSB, R_SUPPLY_V_PER_LSB = R.TEMP_C_AT_ZERO, R.TEMP_C_PER_LSB, R.SUPPLY_V_PER_LSB
    from ahrsd.drivers.adis16405 import _SUPPLY_MAX_LSB, _SUPPLY_MIN_LSB

    prev9, runs9 = np.zeros(9, np.int64), np.zeros(9, np.int64)
    read_one = chip_source.ChipSource.read_one
    new_data, gap, stale = int(SampleFlags.NEW_DATA), int(SampleFlags.GAP_BEFORE), int(SampleFlags.STALE)
    kept: dict = {}

    def compiled(self, now: float):
        timer, driver, clock = self.timer, self.driver, self.clock
        if not (driver.samples_as_records and self._common_timer and timer.hi is not None):
            return read_one(self, now)
        args = kept.get("args")
        if args is None:
            args = kept["args"] = (np.array(driver._full_scale9, np.int64), np.array(driver._scale9_list), prev9,
                                   runs9, driver._gyro_range_lsb, driver._jump_lsb)
        now = max(now, clock())
        self._read_start = now
        rx = driver.read_burst()
        prev_gx = driver._prev_gx
        out = decode(rx, *args, 0 if prev_gx is None else prev_gx, _SUPPLY_MIN_LSB, _SUPPLY_MAX_LSB)
        t = None if out[0] or driver.newer_sample_taken else timer.fresh_after_first(now, clock(), True)
        if t is None:
            s = driver.decode_burst(rx, self._stamp)
            return None if s.flags & stale else s
        driver.counters["new_samples"] += 1
        driver._prev_gx, driver._burst_supply_lsb = out[1], out[2]
        t_s, k, lost = t
        return SampleRecord((t_s, *out[4:], new_data | (gap if lost else 0), 0, k))

    # compiled before the reads start (not at the first read)
    decode(bytes(26), np.ones(9, np.int64), np.ones(9), prev9, runs9, 1, 1, 0, _SUPPLY_MIN_LSB, _SUPPLY_MAX_LSB)
    chip_source.ChipSource.read_one = compiled


def _threads(pid: int) -> dict[str, tuple[float, float, float]]:
    """Per thread of `pid`: user and system CPU seconds (/proc stat) and run time (schedstat)."""
    tck = os.sysconf("SC_CLK_TCK")
    out = {}
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            stat = Path(f"/proc/{pid}/task/{tid}/stat").read_text().rsplit(")", 1)[1].split()
            run_ns = int(Path(f"/proc/{pid}/task/{tid}/schedstat").read_text().split()[0])
        except OSError:
            continue
        out[tid] = (int(stat[11]) / tck, int(stat[12]) / tck, run_ns / 1e9)
    return out


def _part(filename: str, function: str) -> str:
    for name, files in PARTS:
        if filename.endswith(files):
            return name
    return "sleep" if function == "<built-in method time.sleep>" else "other"


def _profile_lines(path: str) -> list[str]:
    """Calls and profiled µs a read by part; a built-in's calls and time go to the part that called it."""
    import pstats

    stats = pstats.Stats(path).stats
    # a read is a call of the chip source's read_one (the common read calls no read_sample: drivers.chip_source)
    reads = sum(v[1] for k, v in stats.items() if k[0].endswith("chip_source.py") and k[2] == "read_one")
    time_s: dict[str, float] = {}
    calls: dict[str, int] = {}
    for (filename, _line, function), (_cc, ncalls, tottime, _ct, callers) in stats.items():
        if filename == "~" and function != "<built-in method time.sleep>":
            for (cf, _cl, cfn), caller in callers.items():
                part = _part(cf, cfn)
                calls[part] = calls.get(part, 0) + caller[1]
                time_s[part] = time_s.get(part, 0.0) + caller[2]
            continue
        part = _part(filename, function)
        calls[part] = calls.get(part, 0) + ncalls
        time_s[part] = time_s.get(part, 0.0) + tottime
    busy = [p for p in time_s if p != "sleep"]
    lines = [f"profiled reads {reads}: {sum(calls[p] for p in busy) / reads:.1f} Python calls a read "
             f"({sum(calls[p] for p in busy if p != 'simulated chip') / reads:.1f} outside the simulated chip), "
             f"{1e6 * sum(time_s[p] for p in busy) / reads:.0f} µs a read profiled"]
    for name in [n for n, _ in PARTS] + ["other"]:
        if name in calls:
            lines.append(f"  {name:36s} {calls[name] / reads:5.1f} calls  {1e6 * time_s[name] / reads:6.1f} µs a read")
    return lines


def numpy_block_decode(frames: int, repeats: int = 5000) -> None:
    """Thread CPU a sample, in a hot loop, of the reader process's per-sample record (the driver's SampleRecord
    from the frame's integers, then `pack`) against decoding a block of `frames` burst frames with numpy at once
    (kept raw at each read, decoded into the same hand-over records at the hand-over): what batching the
    decode would save at the hand-over's block size (70 blocks a second at 819.2 SPS: about 12 frames)."""
    import struct
    from operator import mul

    import numpy as np

    from ahrsd.drivers import registers as R
    from ahrsd.drivers.process_source import _RECORD, pack
    from ahrsd.drivers.sample_record import SampleRecord

    scale9 = [math.radians(0.05)] * 3 + [R.ACCEL_M_S2_PER_LSB] * 3 + [R.MAG_UT_PER_LSB] * 3
    scale = np.array(scale9)
    raw9 = [100, -200, 300, 4000, -10, 20, 1000, -2000, 3000]
    frame = bytes(2) + struct.pack(">12H", 2000, *[r & 0x3FFF for r in raw9], 1234, 0)

    def per_sample() -> bytes:
        records = []
        for i in range(frames):
            temp_c = R.TEMP_C_AT_ZERO + R.TEMP_C_PER_LSB * (((1234 & 0x0FFF) ^ 0x0800) - 0x0800)
            records.append(SampleRecord((0.001 * i, *map(mul, raw9, scale9), temp_c, 2000 * R.SUPPLY_V_PER_LSB,
                                         1, 0, i)))
        return pack(records)

    def numpy_block() -> bytes:
        kept = [(0.001 * i, 1, 0, i, raw9[0], frame) for i in range(frames)]
        n = len(kept)
        words = np.frombuffer(b"".join([k[5] for k in kept]), ">u2").reshape(n, 13)[:, 1:]
        raw = ((words[:, 1:10] & 0x3FFF) ^ 0x2000).astype(np.int64) - 0x2000
        raw[:, 0] = [k[4] for k in kept]
        out = np.empty(n, _RECORD)
        out["t_s"] = [k[0] for k in kept]
        values = raw * scale
        out["gyro"], out["accel"], out["mag"] = values[:, 0:3], values[:, 3:6], values[:, 6:9]
        temp = (((words[:, 10] & 0x0FFF) ^ 0x0800).astype(np.int64) - 0x0800)
        out["temp_c"] = R.TEMP_C_AT_ZERO + R.TEMP_C_PER_LSB * temp
        out["supply_v"] = (words[:, 0] & 0x3FFF) * R.SUPPLY_V_PER_LSB
        out["flags"], out["diag"], out["counter"] = [k[1] for k in kept], [k[2] for k in kept], [k[3] for k in kept]
        return out.tobytes()

    assert per_sample() == numpy_block()          # the same hand-over bytes
    for f in (per_sample, numpy_block, per_sample, numpy_block):
        t0 = time.thread_time()
        for _ in range(repeats):
            f()
        print(f"{f.__name__:12s} {1e6 * (time.thread_time() - t0) / repeats / frames:5.2f} µs a sample "
              f"(blocks of {frames}, hot loop)")


def compiled_decode(repeats: int = 200_000) -> None:
    """Thread CPU a frame, in a hot loop, of the driver's burst checks and decode in Python (Adis16405.read_sample's
    lines from the frame's bytes to the nine signed values: ND/EA agreement, supply bound, sign extension,
    plausibility and full-scale bounds) against one numba call doing the same and returning a tuple: what a
    compiled decode would save per read before the cold caches of a real wake (numba's call and the tuple's boxing
    included). Both give the same answer on a good, a mismatched, an implausible and a saturated frame."""
    import struct
    from operator import ge, gt

    import numba
    import numpy as np

    unpack = struct.Struct(">12H").unpack_from
    lo_lsb, hi_lsb = 1000, 2000                     # supply bounds (drivers.adis16405: 3.0..6.0 V) as LSB here
    plausible9, full9 = [10240] * 9, [8191] * 9
    plausible_a, full_a = np.array(plausible9, np.int64), np.array(full9, np.int64)

    def python(rx):
        w0, w1, w2, w3, w4, w5, w6, w7, w8, w9, w10, _ = unpack(rx, 2)
        both = w0 & w1 & w2 & w3 & w4 & w5 & w6 & w7 & w8 & w9 & 0xC000
        if (w0 | w1 | w2 | w3 | w4 | w5 | w6 | w7 | w8 | w9) & 0xC000 != both:
            return (1,)
        if not lo_lsb <= w0 & 0x3FFF <= hi_lsb:
            return (2,)
        raw9 = [((x & 0x3FFF) ^ 0x2000) - 0x2000 for x in (w1, w2, w3, w4, w5, w6, w7, w8, w9)]
        abs9 = list(map(abs, raw9))
        if any(map(gt, abs9, plausible9)):
            return (3,)
        return (0, both, w0 & 0x3FFF, int(any(map(ge, abs9, full9))), w10, *raw9)

    @numba.njit(cache=False)
    def compiled(rx, plausible, full):
        w = np.empty(12, np.int64)
        for i in range(12):
            w[i] = (rx[2 + 2 * i] << 8) | rx[3 + 2 * i]
        both, either = 0xC000, 0
        for i in range(10):
            both &= w[i]
            either |= w[i]
        if either & 0xC000 != both:
            return (1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)
        if not lo_lsb <= w[0] & 0x3FFF <= hi_lsb:
            return (2, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)
        r = np.empty(9, np.int64)
        sat = 0
        for i in range(9):
            r[i] = ((w[i + 1] & 0x3FFF) ^ 0x2000) - 0x2000
            if abs(r[i]) > plausible[i]:
                return (3, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)
            if abs(r[i]) >= full[i]:
                sat = 1
        return (0, both, w[0] & 0x3FFF, sat, w[10], r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8])

    def frame(supply, raw9, nd=0x8000, first_nd=0x8000):
        words = [supply | first_nd] + [(r & 0x3FFF) | nd for r in raw9]
        return bytes(2) + struct.pack(">12H", *words, 1234, 0)

    good = frame(1500, [100, -200, 300, 4000, -10, 20, 1000, -2000, 3000])
    cases = (good, frame(1500, [100] * 9, nd=0), frame(1500, [100] * 8 + [-12000]), frame(1500, [-8191] + [5] * 8),
             frame(500, [1] * 9))
    for rx in cases:
        want, got = python(rx), compiled(rx, plausible_a, full_a)
        assert tuple(got[:len(want)]) == want, (want, got)
    for f, args in ((python, (good,)), (compiled, (good, plausible_a, full_a))) * 2:
        t0 = time.thread_time()
        for _ in range(repeats):
            f(*args)
        print(f"{f.__name__:9s} {1e6 * (time.thread_time() - t0) / repeats:5.2f} µs a frame (hot loop)")


def hot_reads(reads: int = 20_000) -> dict:
    """The reader thread's per-read step with its caches kept: drivers.threaded_source's loop (pacing, read, timer,
    driver, record) over the simulated chip on a stepped clock whose waits only step it, so the thread runs read
    after read without sleeping. Prints its CPU a read and the simulated chip's part (the transfers, timed in the
    thread); against `--split`'s CPU from a wake to the next wait, the difference is what a read costs more after a
    real sleep. No hand-over tick (no pipe) and no truth bookkeeping here."""
    from ahrsd.drivers.sim_clock import ChipClock
    from ahrsd.drivers.simulated import SimulatedAdis16405
    from ahrsd.drivers.source import start_chip_source
    from ahrsd.drivers.threaded_source import ThreadedSource

    class SteppedClock(ChipClock):
        t = 100.0

        def __call__(self) -> float:
            return self.t

        def sleep(self, seconds: float) -> None:
            self.t += max(0.0, seconds)

        def sleep_until(self, t: float) -> None:
            self.t = max(self.t, t)

    clock = SteppedClock()
    chip = SimulatedAdis16405("static", seed=3, clock=clock)
    inner = start_chip_source(chip, "bench chip", clock=clock, self_test=False)
    inner.driver.samples_as_records = True
    chip_ns = [0]
    transfer = chip.transfer

    def timed_transfer(*args):
        t0 = time.thread_time_ns()
        try:
            return transfer(*args)
        finally:
            chip_ns[0] += time.thread_time_ns() - t0

    chip.transfer = timed_transfer
    # room for every sample: each read hands its sample over as the reader's does (none dropped at a full buffer)
    src = ThreadedSource(inner, clock=clock, sleep_until=clock.sleep_until, realtime=False, switch_interval_s=None,
                         capacity_samples=2 * (1000 + reads))
    marks: list[tuple[int, int, int]] = []      # (loops, thread CPU ns, chip ns) at the warm-up's end and the end

    def count_loops(n=[0]):
        n[0] += 1
        if n[0] in (1000, 1000 + reads):
            marks.append((n[0], time.thread_time_ns(), chip_ns[0]))
            if len(marks) == 2:
                src._stop.set()

    src.after_read = count_loops
    src.start()
    src._thread.join()
    src.close()
    (n0, cpu0, chip0), (n1, cpu1, chip1) = marks
    return {"loops": n1 - n0, "cpu_s": (cpu1 - cpu0) / 1e9, "chip_s": (chip1 - chip0) / 1e9,
            "reads": src.stats["reads"], "stale": inner.stale_reads, "handed_over": len(src.poll())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--hz", type=float, default=70.0, help="hand-overs a second the daemon asks for")
    ap.add_argument("--profile", action="store_true", help="the reader thread under cProfile: calls a read by part")
    ap.add_argument("--split", action="store_true",
                    help="also count the reader thread's CPU from each wake's return to the next wait")
    ap.add_argument("--bound", action="store_true",
                    help="the common read cut to the transfer, the timer's step and a record made once: what a "
                         "faster frame decode could save at most (not a reader: the frames are not looked at)")
    ap.add_argument("--compiled-read", action="store_true",
                    help="the common read's frame decode in one numba call (not a reader: a measurement)")
    ap.add_argument("--import-numba", action="store_true",
                    help="the reader process imports numba before it opens the chip (its start's cost)")
    ap.add_argument("--compiled-decode", action="store_true",
                    help="only time, in a hot loop, the driver's burst checks and decode in Python against numba")
    ap.add_argument("--hot", type=int, default=0, metavar="N",
                    help="only the reader thread's per-read step, N reads back to back on a stepped clock "
                         "(caches kept)")
    ap.add_argument("--numpy-block", type=int, default=0, metavar="N",
                    help="only time, in a hot loop, the per-sample record against decoding N frames with numpy")
    args = ap.parse_args()
    if args.hot:
        r = hot_reads(args.hot)
        loops, cpu_s, chip_s = r["loops"], r["cpu_s"], r["chip_s"]
        print(f"hot: {loops} loops, {1e6 * cpu_s / loops:.1f} µs of thread CPU a loop, of which the simulated chip's "
              f"transfers {1e6 * chip_s / loops:.1f} µs: {1e6 * (cpu_s - chip_s) / loops:.1f} µs without them "
              f"({r['reads']} reads, {r['stale']} of them stale, {r['handed_over']} samples handed over)")
        return
    if args.compiled_decode:
        compiled_decode()
        return
    if args.numpy_block:
        numpy_block_decode(args.numpy_block)
        return

    from ahrsd.daemon.config import SensorConfig
    from ahrsd.drivers import process_source

    profile_path = ""
    if args.profile:
        import tempfile

        profile_path = os.path.join(tempfile.mkdtemp(prefix="reader_calls_"), "reader.prof")
        os.environ["READER_CALLS_PROFILE"] = profile_path
    if args.split:
        os.environ["READER_CALLS_SPLIT"] = "1"
    if args.bound:
        os.environ["READER_CALLS_BOUND"] = "1"
    if args.import_numba:
        os.environ["READER_CALLS_IMPORT_NUMBA"] = "1"
    if args.compiled_read:
        os.environ["READER_CALLS_COMPILED"] = "1"
    process_source._child = child
    load0 = os.getloadavg()[0]
    spawned = time.monotonic()
    src = process_source.ProcessSource(SensorConfig(source="sim", reader="process"))
    started = time.monotonic()          # the reader process spawned, its imports done, the chip started
    first_sample: list[float] = []
    period = 1.0 / args.hz

    def take(until: float) -> int:
        n = 0
        src.hand_over_by(math.ceil(time.monotonic() / period) * period)
        while time.monotonic() < until:
            if select.select([src.ready_fd], [], [], 0.05)[0]:
                n += len(src.poll())
                if n and not first_sample:
                    first_sample.append(time.monotonic())
                src.hand_over_by(math.ceil(time.monotonic() / period) * period)
        return n

    try:
        src.poll()                                        # "go": the reader starts
        take(time.monotonic() + 4.0)
        time.sleep(0.3)                                   # the next counters
        src.poll()
        c0, t0, wall0 = dict(src.counters()), _threads(src._proc.pid), time.monotonic()
        taken = take(wall0 + args.seconds)
        time.sleep(0.3)
        taken += len(src.poll())
        c1, t1, wall1 = src.counters(), _threads(src._proc.pid), time.monotonic()
    finally:
        src.close()
    secs = wall1 - wall0
    reads = c1["reader_reads"] - c0["reader_reads"]
    print(f"machine: {os.cpu_count()} CPUs, load average {load0:.2f} → {os.getloadavg()[0]:.2f}; {secs:.1f} s, "
          f"{reads / secs:.1f} reads a second, {taken / secs:.1f} samples taken a second, {args.hz:g} hand-overs asked")
    if first_sample:
        print(f"the reader process: started {started - spawned:.2f} s after its spawn, the first sample taken "
              f"{first_sample[0] - spawned:.2f} s after the spawn")
    busiest = max((tid for tid in t1 if tid in t0), key=lambda tid: t1[tid][2] - t0[tid][2])
    user, sys_, run = (t1[busiest][i] - t0[busiest][i] for i in range(3))
    sim = c1.get("sensor_simulated_cpu_s", 0.0) - c0.get("sensor_simulated_cpu_s", 0.0)
    print(f"reader thread: {100 * run / secs:.2f} % of a core (user {100 * user / secs:.2f}, system "
          f"{100 * sys_ / secs:.2f}), {1e6 * run / reads:.1f} µs a read; of it the simulated chip "
          f"{100 * sim / secs:.2f} % ({1e6 * sim / reads:.1f} µs a read); own {1e6 * (run - sim) / reads:.1f} µs a read")
    others = sum(t1[tid][2] - t0[tid][2] for tid in t1 if tid in t0 and tid != busiest)
    print(f"the reader process's other threads: {100 * others / secs:.2f} % of a core")
    loops = c1.get("reader_split_loops", 0) - c0.get("reader_split_loops", 0)
    if loops:
        work_s = (c1["reader_split_work_ns"] - c0["reader_split_work_ns"]) / 1e9
        print(f"split: {loops / secs:.1f} loops a second, {1e6 * work_s / loops:.1f} µs of thread CPU "
              f"from a wake to the next wait ({1e6 * (work_s - sim) / loops:.1f} µs without the simulated chip); "
              f"the wait itself {1e6 * (run - work_s) / loops:.1f} µs")
    if profile_path:
        for line in _profile_lines(profile_path):
            print(line)


if __name__ == "__main__":
    main()
