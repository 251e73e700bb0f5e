"""Where the daemon's event loop spends its CPU, counted in the running daemon: `ahrsd` run with every event-loop
callback, the loop's iterations and a few named parts timed with the thread's CPU clock (`time.thread_time`,
CLOCK_THREAD_CPUTIME_ID), so the split is per wake, per sample block, per GNSS fix and per output, in CPU time
and calls, not sampled wall time. bench/latency.py `--split` runs the daemon through this and prints the split
over its window; alone:

    .venv/bin/python bench/loop_split.py OUT.jsonl -- run --sim boat --gnss-sim --config ahrsd.toml ...

Each SIGUSR1 appends one JSON line to OUT.jsonl: the loop thread's CPU seconds, the monotonic time and, per timed
part, [calls, CPU seconds, items] since the start (items: samples for the per-sample path, messages sent for
an endpoint). The difference of two lines is the split over the time between them.

Timed parts (names in the output):
- `callback <qualname>`: each loop callback (asyncio Handle._run: a reader's descriptor, a timer, a task's step),
  keyed by what it calls; together they are the loop's work;
- `loop iteration`: asyncio's `_run_once` as a whole (callbacks, the selector's wait and the loop's own
  bookkeeping), `selector wait`: the selector's `select` (the system call's CPU, not the time it waited);
- nested inside the callbacks (their CPU is also in the callback's): `take blocks` (ProcessSource.poll: the
  pipe and the unpacking), `per-sample path` (SampleReader.process; items = samples), `outputs`
  (Publishers.publish), `endpoint send` (Endpoint.send; items = messages sent), `GNSS fix` (GnssTask.deliver),
  `ins GNSS update` (the aided estimator's update_gnss), `hand-over deadline` (ProcessSource.hand_over_by with
  the next-due computation), `last estimate (snapshot built at the first ask)` (Pipeline.last_estimate: the
  outputs ask first after a block, and ins builds its AttitudeEstimate then), `per-sample path: listener <name>`
  (a sample listener; items = samples) and `per-sample path: run listener <name>` (a listener's run form,
  daemon.sample_reader.SampleListeners `runs=`; items = the run's samples); `per-sample path: late samples counted`
  (items = samples used LATE_AFTER_S or more after they were ready, daemon.sample_reader; its CPU is not timed);
  `gc generation N`: the garbage collector's collections (items = objects collected),
  in whichever thread allocated.
The clock itself is a system call (about 0.5–3 µs here): two per timed call, in every part's figure.
"""

from __future__ import annotations

import json
import signal
import sys
import time
from pathlib import Path

_clock = time.thread_time
PARTS: dict[str, list] = {}


def _timed(name: str, fn, items=None):
    rec = PARTS.setdefault(name, [0, 0.0, 0])

    def wrapper(*args, **kwargs):
        t0 = _clock()
        try:
            return fn(*args, **kwargs)
        finally:
            rec[0] += 1
            rec[1] += _clock() - t0
            if items is not None:
                rec[2] += items(args)
    wrapper.__wrapped__ = fn
    wrapper.__qualname__ = getattr(fn, "__qualname__", name)
    return wrapper


def _callback_name(cb) -> str:
    fn = getattr(cb, "__func__", cb)
    name = getattr(fn, "__qualname__", None)
    if name is None:
        name = type(cb).__name__
        task = getattr(cb, "__self__", None)
        coro = getattr(task, "get_coro", lambda: None)() if task is not None else None
        if coro is not None:
            name += f" ({getattr(coro, '__qualname__', '?')})"
    return name


def _count_collections() -> None:
    """The garbage collector's collections in this process, per generation (`gc.callbacks`): calls and the
    collecting thread's CPU, as parts "gc generation N" (a collection runs in the thread that allocates: here
    mostly the event loop)."""
    import gc

    started: list[float] = [0.0]

    def callback(phase: str, info: dict) -> None:
        if phase == "start":
            started[0] = _clock()
            return
        rec = PARTS.setdefault(f"gc generation {info['generation']}", [0, 0.0, 0])
        rec[0] += 1
        rec[1] += _clock() - started[0]
        rec[2] += info.get("collected", 0)
    gc.callbacks.append(callback)


def install() -> None:
    _count_collections()
    import asyncio.base_events
    import asyncio.events
    import selectors

    handle_run = asyncio.events.Handle._run

    def run(self):
        name = "callback " + _callback_name(self._callback)
        rec = PARTS.get(name)
        if rec is None:
            rec = PARTS[name] = [0, 0.0, 0]
        t0 = _clock()
        try:
            return handle_run(self)
        finally:
            rec[0] += 1
            rec[1] += _clock() - t0
    asyncio.events.Handle._run = run
    asyncio.base_events.BaseEventLoop._run_once = _timed("loop iteration", asyncio.base_events.BaseEventLoop._run_once)
    selector = selectors.DefaultSelector
    selector.select = _timed("selector wait", selector.select)

    from ahrsd.daemon.gnss_task import GnssTask
    from ahrsd.daemon.mavlink_io import Endpoint
    from ahrsd.daemon.publishers import Publishers
    from ahrsd.daemon.sample_reader import SampleReader
    from ahrsd.drivers.process_source import ProcessSource
    from ahrsd.estimator.ins import Ins

    from ahrsd.daemon.housekeeping import Housekeeping
    from ahrsd.daemon.output_registry import OUTPUTS
    from ahrsd.daemon.outputs import OutputSchedule
    from ahrsd.daemon.pipeline import Pipeline
    from ahrsd.daemon.sample_reader import SampleListeners
    from ahrsd.drivers import process_source

    ProcessSource.poll = _timed("take blocks", ProcessSource.poll)
    process_source.unpack_block = _timed("take blocks: unpack", process_source.unpack_block)
    process_source.receive = _timed("take blocks: receive a message", process_source.receive)
    estimator_setter = Pipeline.estimator.fset

    def timed_estimator(self, estimator) -> None:          # the step the pipeline calls, timed (per instance)
        estimator_setter(self, estimator)
        if self._step is not None:
            self._step = _timed("per-sample path: estimator step", self._step)
    Pipeline.estimator = Pipeline.estimator.setter(timed_estimator)
    add = SampleListeners.add

    def timed_add(self, fn, **kw):
        runs = kw.get("runs")
        if runs is not None:                           # its run form (items = the run's samples)
            kw["runs"] = (_timed("per-sample path: run listener " + _callback_name(runs[0]), runs[0],
                                 items=lambda a: len(a[0])), runs[1])
        return add(self, _timed("per-sample path: listener " + _callback_name(fn), fn), **kw)
    SampleListeners.add = timed_add
    for spec in OUTPUTS:
        object.__setattr__(spec, "build", _timed("outputs: build " + spec.config_key[:-3], spec.build))
    OutputSchedule.due = _timed("outputs: schedule due", OutputSchedule.due)
    init = Housekeeping.__init__
    Housekeeping.__init__ = lambda self, jobs: init(self, [_timed("housekeeping: " + _callback_name(j), j)
                                                           for j in jobs])
    ProcessSource.hand_over_by = _timed("hand-over deadline", ProcessSource.hand_over_by)
    SampleReader.process = _timed("per-sample path", SampleReader.process, items=lambda a: len(a[1]))
    count_late = SampleReader._count_late
    late = PARTS.setdefault("per-sample path: late samples counted", [0, 0.0, 0])

    def counted_late(self, block, ready_by):
        before = self.counters.late_samples
        count_late(self, block, ready_by)
        late[0] += 1
        late[2] += self.counters.late_samples - before
    SampleReader._count_late = counted_late
    Publishers.publish = _timed("outputs", Publishers.publish)
    # the latest estimate asked for (the outputs first, housekeeping too): ins builds its snapshot at the first ask
    # after a block (estimator/estimate_view.py), the outputs' largest part
    Pipeline.last_estimate = property(_timed("last estimate (snapshot built at the first ask)",
                                             Pipeline.last_estimate.fget))
    Publishers.next_due = _timed("next output due", Publishers.next_due)
    Endpoint.send = _timed("endpoint send", Endpoint.send, items=lambda a: 1)
    GnssTask.deliver = _timed("GNSS fix", GnssTask.deliver)
    for part in ("_report_state", "_watch_gate", "_watch_fitted_arm"):
        setattr(GnssTask, part, _timed("housekeeping: GnssTask.tick: " + part, getattr(GnssTask, part)))
    from ahrsd.estimator.lever_arm_fit import LeverArmFit
    LeverArmFit._fit = _timed("lever-arm fit (recomputed)", LeverArmFit._fit)
    Ins.update_gnss = _timed("ins GNSS update", Ins.update_gnss)


def main() -> int:
    out = Path(sys.argv[1])
    argv = sys.argv[sys.argv.index("--") + 1:]

    def snapshot(signum, frame) -> None:
        line = {"t": time.monotonic(), "loop_cpu_s": _clock(), "parts": {k: list(v) for k, v in PARTS.items()}}
        with out.open("a") as f:
            f.write(json.dumps(line) + "\n")

    signal.signal(signal.SIGUSR1, snapshot)
    install()
    from ahrsd.cli.main import main as cli_main

    return cli_main(argv)


def split(line0: dict, line1: dict) -> tuple[float, float, list[tuple[str, float, float, float, float]]]:
    """(window s, the loop thread's CPU share, rows): per part, (name, calls a second, µs of CPU a call, % of a
    core, items a second), busiest first."""
    wall = line1["t"] - line0["t"]
    rows = []
    for name, (n1, c1, i1) in line1["parts"].items():
        n0, c0, i0 = line0["parts"].get(name, (0, 0.0, 0))
        if n1 == n0:
            continue
        rows.append((name, (n1 - n0) / wall, (c1 - c0) / (n1 - n0) * 1e6, 100 * (c1 - c0) / wall, (i1 - i0) / wall))
    return wall, 100 * (line1["loop_cpu_s"] - line0["loop_cpu_s"]) / wall, sorted(rows, key=lambda r: -r[3])


if __name__ == "__main__":
    sys.exit(main())
