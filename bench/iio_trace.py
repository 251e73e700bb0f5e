"""Where the IIO path's output latency goes, traced in the running daemon: `ahrsd` run with the IIO reader thread's
reads and hand-overs, the event loop's polls and the loop's long callbacks stamped with CLOCK_MONOTONIC, so each
VISION_POSITION_ESTIMATE that bench/latency.py receives (`--trace`) is split into the stages between its sample
becoming ready and its datagram arriving:

- `age at read`: the read that took the sample (drivers.iio_source IioSource.poll, its start) − the sample's time
  stamp: how old the newest record was when the reader read the kernel's buffer (up to a sample period when the
  read falls between two records, more when the record came late);
- `read -> hand-over`: the read's start to the block handed over (os.read and decode, and a wait for the first
  record after a deadline that found none);
- `hand-over -> loop`: to the event loop's poll of the block (the eventfd wake, the loop's other work, the GIL);
- `loop -> sent`: the poll to the end of the loop's step (the per-sample path and the outputs, the send inside);
- `sent -> arrival`: to the bench's receipt of the datagram (its own wake);
- and `deadline -> read`: the read's start − the output deadline it served (the reader thread's wake).

    .venv/bin/python bench/iio_trace.py OUT.json -- run --iio ... (bench/latency.py --trace runs it so)

OUT.json is written when the daemon exits: the reads, hand-overs, polls and loop callbacks longer than 0.5 ms.
"""

from __future__ import annotations

import atexit
import json
import sys
import time
from pathlib import Path

_now = time.monotonic
READS: list = []          # (start, end, n records) of each IioSource.poll in the reader thread
HANDOVERS: list = []      # (t, newest t_s, n, due_s, served) of each ThreadedSource._hand_over_block
POLLS: list = []          # (enter, exit, newest t_s or None) of each SampleReader._batch_step's poll
LONG: list = []           # (start, end, name) of loop callbacks longer than LONG_S
FIXES: list = []          # (start, end, 1) of each GnssTask.deliver (the validator, the log, ins, the subscribers)
LONG_S = 0.0005


def install() -> None:
    import asyncio.events

    from ahrsd.daemon.sample_reader import SampleReader
    from ahrsd.drivers.iio_source import IioSource
    from ahrsd.drivers.threaded_source import ThreadedSource

    poll = IioSource.poll

    def traced_poll(self):
        t0 = _now()
        block = poll(self)
        READS.append((t0, _now(), len(block)))
        return block

    IioSource.poll = traced_poll
    hand_over_block = ThreadedSource._hand_over_block

    def traced_hand_over(self, block):
        plan = self._plan
        HANDOVERS.append((_now(), block.t_s[-1] if len(block) else None, len(block), plan.due_s, plan.served_s))
        return hand_over_block(self, block)

    ThreadedSource._hand_over_block = traced_hand_over
    tpoll = ThreadedSource.poll
    current: dict = {}

    def traced_tpoll(self):
        current["enter"] = _now()
        out = tpoll(self)
        current["newest"] = out.t_s[-1] if len(out) else None
        return out

    ThreadedSource.poll = traced_tpoll
    step = SampleReader._batch_step

    def traced_step(self, on_data=False):
        current.clear()
        step(self, on_data)
        if "enter" in current:
            POLLS.append((current["enter"], _now(), current.get("newest")))

    SampleReader._batch_step = traced_step
    from ahrsd.daemon.gnss_task import GnssTask

    deliver = GnssTask.deliver

    def traced_deliver(self, fix):
        t0 = _now()
        deliver(self, fix)
        FIXES.append((t0, _now(), 1))

    GnssTask.deliver = traced_deliver
    run = asyncio.events.Handle._run

    def traced_run(self):
        t0 = _now()
        run(self)
        t1 = _now()
        if t1 - t0 > LONG_S:
            cb = self._callback
            LONG.append((t0, t1, getattr(cb, "__qualname__", repr(cb))[:80]))

    asyncio.events.Handle._run = traced_run
    import gc

    started: list = [0.0]

    def gc_pause(phase, info):           # the collector's pauses, in whichever thread allocated
        if phase == "start":
            started[0] = _now()
        elif _now() - started[0] > LONG_S:
            LONG.append((started[0], _now(), f"gc generation {info['generation']}"))

    gc.callbacks.append(gc_pause)


def main() -> int:
    out = Path(sys.argv[1])
    argv = sys.argv[sys.argv.index("--") + 1:]

    def dump() -> None:
        out.write_text(json.dumps({"reads": READS, "handovers": HANDOVERS, "polls": POLLS, "long": LONG,
                                   "fixes": FIXES}))

    atexit.register(dump)
    install()
    from ahrsd.cli.main import main as cli_main

    return cli_main(argv)


def stages(trace: dict, vpe: list[tuple[int, float]], t0: float, t1: float) -> dict[str, list[float]]:
    """Per VPE received between t0 and t1 ((usec, arrival) pairs), its stages in seconds (the module doc), matched
    by the sample's time stamp to the hand-over and the poll that carried it."""
    import bisect

    reads = trace["reads"]
    read_starts = [r[0] for r in reads]
    # keyed as the VPE's usec is made (daemon.output_registry: int of µs)
    by_newest_ho = {int(h[1] * 1e6): h for h in trace["handovers"] if h[1] is not None}
    by_newest_poll = {int(p[2] * 1e6): p for p in trace["polls"] if p[2] is not None}
    out: dict[str, list] = {k: [] for k in ("total", "age at read", "read -> hand-over", "hand-over -> loop",
                                            "loop -> sent", "sent -> arrival", "deadline -> read", "blocking",
                                            "fix before", "fix in front", "other before")}
    others = [c for c in trace["long"] if "_batch_step" not in c[2] and "_data_step" not in c[2]]
    fixes = trace.get("fixes", [])
    fix_ends = [f[1] for f in fixes]
    fix_starts = [f[0] for f in fixes]
    longs = [c for c in trace["long"] if "_data_step" not in c[2]]
    for usec, arrival in vpe:
        if not t0 <= arrival <= t1:
            continue
        ho, pl = by_newest_ho.get(usec), by_newest_poll.get(usec)
        if ho is None or pl is None:
            continue
        i = bisect.bisect_right(read_starts, ho[0]) - 1      # the last read started before the hand-over
        if i < 0:
            continue
        read_start = reads[i][0]
        t_s = usec * 1e-6
        # a fix delivered inside the step (GnssTask's after_output) runs after the outputs were sent: the step's sent
        # time is then where that fix started
        j = bisect.bisect_right(fix_starts, pl[0])
        sent = fixes[j][0] if j < len(fixes) and fixes[j][0] < pl[1] else pl[1]
        pl = (pl[0], sent, pl[2])
        out["total"].append(arrival - t_s)
        out["age at read"].append(read_start - t_s)
        out["read -> hand-over"].append(ho[0] - read_start)
        out["hand-over -> loop"].append(pl[0] - ho[0])
        out["loop -> sent"].append(pl[1] - pl[0])
        out["sent -> arrival"].append(arrival - pl[1])
        if ho[3] != float("inf") and ho[4] == ho[3]:
            out["deadline -> read"].append(read_start - ho[3])
        # another loop callback (not the block's) that ran while the block waited for the loop
        out["blocking"].append(next((c[2] for c in longs if c[0] < pl[0] and c[1] > ho[0]), ""))
        out["fix before"].append(fix_before(fixes, fix_ends, t_s, pl[1]))
        out["fix in front"].append(fix_before(fixes, fix_ends, t_s, pl[1], 0.0))
        # any other long loop callback (housekeeping, a GNSS poll, inbound MAVLink) in that same window
        out["other before"].append(next((c[2] for c in others if c[1] > t_s - FIX_BEFORE_S and c[0] < pl[1]), ""))
    return out


FIX_BEFORE_S = 0.010      # a fix processed this long before a sample's time stamp can still hold its output back


def fix_before(fixes: list, fix_ends: list, t_s: float, sent: float, before_s: float = FIX_BEFORE_S) -> float:
    """The loop's time (s) spent delivering GNSS fixes (GnssTask.deliver) between `before_s` before the
    sample's time stamp and its datagram sent: 0 when no fix ran in that window. With before_s 0: the fixes that ran
    in front of the sample's output, after the sample was ready."""
    import bisect

    i = bisect.bisect_left(fix_ends, t_s - before_s)
    busy = 0.0
    while i < len(fixes) and fixes[i][0] < sent:
        busy += min(fixes[i][1], sent) - max(fixes[i][0], t_s - before_s)
        i += 1
    return busy


def stage_table(trace: dict, vpe: list[tuple[int, float]], t0: float, t1: float) -> list[str]:
    """Lines: each stage's p50 / p99 / max, and the stages of the VPEs in the total's slowest 1 %."""
    import numpy as np

    st = stages(trace, vpe, t0, t1)
    blocking = st.pop("blocking")
    fix_busy = np.array(st.pop("fix before")) * 1e3
    in_front = np.array(st.pop("fix in front")) * 1e3 > 0
    other_before = st.pop("other before")
    n = len(st["total"])
    if not n:
        return ["   trace: no VPE matched"]
    lines = [f"   trace ({n} VPE matched): stage p50 / p99 / max ms; mean over the slowest 1 % of totals"]
    total = np.array(st["total"])
    slow = total >= np.percentile(total, 99)
    for name, vals in st.items():
        v = np.array(vals) * 1e3
        tail = f"{np.mean(v[slow]):7.3f}" if len(v) == n else "      -"
        lines.append(f"     {name:18s} {np.percentile(v, 50):7.3f} / {np.percentile(v, 99):7.3f} / {v.max():7.3f}"
                     f"   slowest-1% mean {tail}")
    slow_blocked: dict[str, int] = {}
    for b, s in zip(blocking, slow):
        if s:
            slow_blocked[b or "(none: preempted, GIL)"] = slow_blocked.get(b or "(none: preempted, GIL)", 0) + 1
    lines.append(f"     slowest 1 %: the loop busy with {slow_blocked} while the block waited")
    with_fix = fix_busy > 0
    slow_other: dict[str, int] = {}
    for b, s in zip(other_before, slow):
        if s:
            slow_other[b or "(none)"] = slow_other.get(b or "(none)", 0) + 1
    lines.append(f"     slowest 1 %: a loop callback > 0.5 ms from {1e3 * FIX_BEFORE_S:.0f} ms before the sample to its "
                 f"send: {slow_other}; all VPEs: {100 * np.mean([bool(b) for b in other_before]):.1f} % with one")
    fixes = [f for f in trace.get("fixes", []) if t0 <= f[0] <= t1]
    fix_ms = np.array([(b - a) * 1e3 for a, b, _n in fixes]) if fixes else np.zeros(1)
    lines.append(f"     GNSS fix on the loop from {1e3 * FIX_BEFORE_S:.0f} ms before the sample to its send: slowest 1 % "
                 f"{int(np.sum(with_fix & slow))} of {int(np.sum(slow))}, all {100 * np.mean(with_fix):.1f} %; "
                 f"slowest 1 % with one: its fix time mean {np.mean(fix_busy[with_fix & slow]) if np.any(with_fix & slow) else 0:.2f} ms")
    lines.append(f"     GNSS fix on the loop after the sample was ready, before its send: slowest 1 % "
                 f"{int(np.sum(in_front & slow))} of {int(np.sum(slow))}, all {100 * np.mean(in_front):.1f} %; p99 of "
                 f"totals with one {np.percentile(total[in_front] * 1e3, 99) if np.any(in_front) else 0:.3f} ms")
    lines.append(f"     GNSS fixes: {len(fixes) / (t1 - t0):.1f}/s, loop time a fix p50 / p99 / max {np.percentile(fix_ms, 50):.2f} / "
                 f"{np.percentile(fix_ms, 99):.2f} / {fix_ms.max():.2f} ms; p99 of totals without a fix before "
                 f"{np.percentile(total[~with_fix] * 1e3, 99) if np.any(~with_fix) else 0:.3f} ms, with "
                 f"{np.percentile(total[with_fix] * 1e3, 99) if np.any(with_fix) else 0:.3f} ms")
    window = t1 - t0
    polls = [p for p in trace["polls"] if t0 <= p[0] <= t1]
    lines.append(f"     a second: reads {sum(t0 <= r[0] <= t1 for r in trace['reads']) / window:.1f}, hand-overs "
                 f"{sum(t0 <= h[0] <= t1 for h in trace['handovers']) / window:.1f}, the loop's polls "
                 f"{len(polls) / window:.1f} (empty {sum(p[2] is None for p in polls) / window:.1f})")
    longs = [c for c in trace["long"] if t0 <= c[0] <= t1]
    names: dict[str, list[float]] = {}
    for a, b, name in longs:
        names.setdefault(name, []).append((b - a) * 1e3)
    for a, b, name in longs:
        if b - a > 0.02:
            lines.append(f"     longer than 20 ms: {name[:50]} {1e3 * (b - a):.1f} ms at {a - t0:.1f} s in the window")
    for name, ms in sorted(names.items(), key=lambda kv: -sum(kv[1]))[:6]:
        lines.append(f"     loop callback > 0.5 ms: {name[:50]:50s} {len(ms) / (t1 - t0):6.2f}/s  "
                     f"max {max(ms):6.2f} ms")
    return lines


if __name__ == "__main__":
    sys.exit(main())
