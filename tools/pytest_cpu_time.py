"""pytest plugin: CPU seconds (user + sys, this process and its waited-for children) spent by each test file.

Off by default; load it with `python -m pytest -p tools.pytest_cpu_time ...` from the repository root. It prints
the files by CPU at the end of the run. With pytest-xdist each worker appends its tests to
`$AHRSD_CPU_TIME_OUT-<worker>.jsonl` when that variable is set (the controller sees no test run), and
`python tools/pytest_cpu_time.py FILE...` sums such files per test file; with `--timeline` it prints each worker's
files in the order it ran them, with their wall spans, and when each worker ran out of work (the run's critical
path under `--dist loadfile`: a worker that ends early leaves its core idle while another finishes a long file).

Why CPU and not wall: the suite runs on a shared 2-core machine where wall time follows the load; the CPU a test
spends is what it takes from the other workers. Children are counted when they have been waited for, so a daemon
subprocess a test starts and ends counts towards that test."""

from __future__ import annotations

import collections
import json
import os
import resource
import sys
import time

import pytest


def _children_cpu_s() -> float:
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return children.ru_utime + children.ru_stime


def _cpu_s() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF)
    return own.ru_utime + own.ru_stime + _children_cpu_s()


_per_test: dict[str, float] = {}


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """Runs where the test runs (an xdist worker, or this process without -n): setup, call and teardown."""
    started_s, children_started_s = _cpu_s(), _children_cpu_s()
    wall_started_s = time.time()
    yield
    _per_test[item.nodeid] = _cpu_s() - started_s
    out = os.environ.get("AHRSD_CPU_TIME_OUT")
    if out:
        worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
        row = {"test": item.nodeid, "cpu_s": _per_test[item.nodeid], "worker": worker,
               "children_cpu_s": _children_cpu_s() - children_started_s,
               "wall_start_s": wall_started_s, "wall_end_s": time.time()}
        with open(f"{out}-{worker}.jsonl", "a") as fh:
            fh.write(json.dumps(row) + "\n")


def pytest_sessionfinish(session):
    """Where tests ran: the process's whole CPU at the end of the session (start-up, collection, and what no test
    waited for), beside the tests' sum; the difference is what no test row holds."""
    out = os.environ.get("AHRSD_CPU_TIME_OUT")
    if out and _per_test:
        worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
        with open(f"{out}-{worker}.jsonl", "a") as fh:
            fh.write(json.dumps({"session_of": worker, "cpu_s": _cpu_s(), "children_cpu_s": _children_cpu_s(),
                                 "tests_cpu_s": sum(_per_test.values())}) + "\n")


def per_file(per_test: dict[str, float]) -> list[tuple[str, float, int]]:
    totals: dict[str, list] = collections.defaultdict(lambda: [0.0, 0])
    for nodeid, cpu_s in per_test.items():
        entry = totals[nodeid.split("::")[0]]
        entry[0] += cpu_s
        entry[1] += 1
    return sorted(((f, s, n) for f, (s, n) in totals.items()), key=lambda row: -row[1])


def _print(rows, write) -> None:
    write(f"{'CPU-s':>8} {'tests':>5}  file")
    for name, cpu_s, n in rows:
        write(f"{cpu_s:8.1f} {n:5d}  {name}")
    write(f"{sum(r[1] for r in rows):8.1f} {sum(r[2] for r in rows):5d}  total")


def pytest_terminal_summary(terminalreporter):
    if not _per_test:
        return
    terminalreporter.section("CPU seconds per test file")
    _print(per_file(_per_test), terminalreporter.write_line)
    slow = sorted(_per_test.items(), key=lambda kv: -kv[1])[:15]
    terminalreporter.write_line("slowest tests (CPU-s):")
    for nodeid, cpu_s in slow:
        terminalreporter.write_line(f"{cpu_s:8.1f}  {nodeid}")


def _print_timeline(rows: list[dict], write) -> None:
    """Each worker's files in run order: start and end (s after the first test began), wall span, CPU."""
    t0 = min(r["wall_start_s"] for r in rows)
    by_worker: dict[str, list[dict]] = collections.defaultdict(list)
    for r in rows:
        by_worker[r["worker"]].append(r)
    for worker, tests in sorted(by_worker.items()):
        tests.sort(key=lambda r: r["wall_start_s"])
        write(f"{worker}: last test ended at {tests[-1]['wall_end_s'] - t0:.1f} s")
        files: dict[str, list[float]] = {}
        for r in tests:
            entry = files.setdefault(r["test"].split("::")[0], [r["wall_start_s"], 0.0, 0.0])
            entry[1] = r["wall_end_s"]
            entry[2] += r["cpu_s"]
        for name, (start, end, cpu_s) in files.items():
            write(f"  {start - t0:7.1f} {end - t0:7.1f} wall {end - start:6.1f} CPU {cpu_s:6.1f}  {name}")


if __name__ == "__main__":
    args = sys.argv[1:]
    timeline = "--timeline" in args
    rows = []
    for path in (a for a in args if a != "--timeline"):
        with open(path) as fh:
            rows.extend(json.loads(line) for line in fh)
    sessions = [r for r in rows if "session_of" in r]
    rows = [r for r in rows if "test" in r]
    if timeline:
        _print_timeline([r for r in rows if "wall_start_s" in r], print)
    else:
        _print(per_file({r["test"]: r["cpu_s"] for r in rows}), print)
    for r in sessions:
        print(f"{r['session_of']}: {r['cpu_s']:.1f} CPU-s in all ({r['children_cpu_s']:.1f} in waited-for children), "
              f"{r['cpu_s'] - r['tests_cpu_s']:.1f} outside its tests")
