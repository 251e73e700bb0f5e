"""Break guarded behaviours one at a time and run the tests that should notice (docs/testing.md).

Usage: python tools/mutation_check.py [--list] [--check] [--tests FILE]... [NAME ...]   (from the checkout's root)

Each entry of `MUTATIONS` (tools/mutations.py) is one behaviour, one break of it (a text substitution inside one
line of one file: `old` must occur exactly once in that file) and the test files that guard it. For each
entry this copies the checkout (without .git, .venv and caches) into a temporary directory, applies the break
there, and runs `python -m pytest -x -q -p no:cacheprovider <tests>` in the copy with PYTHONPATH pointing at it
(so the copy, not the installed checkout, is imported: also by the daemons and commands the tests start). The
checkout itself is never written, so Ctrl-C leaves nothing to restore; the copy is removed on the way out.
Prints one line per entry: caught (the tests failed), SURVIVED (they passed with the behaviour broken) or ERROR
(pytest ended otherwise: a collection error, which says nothing about the tests' power), and exits 1 when any
survived or ended in an error.

--check: only that every `old` still occurs exactly once (no test run; tests/test_mutation_table.py runs it).
--list: the entries' names and behaviours.
--tests: run these test files instead of each entry's own (does a new test catch the break?).

The numba kernels compile once per kernel source (estimator/kernel_cache.py digests them): the copy is always
made at the same path and NUMBA_CACHE_DIR is one directory beside it, so an entry that does not touch a kernel
reuses the kernels the first run compiled. Only one run at a time (a lock file says so)."""

from __future__ import annotations

import argparse
import dataclasses
import fcntl
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))

from mutations import MUTATIONS, Mutation  # noqa: E402

IGNORED = shutil.ignore_patterns(".git", ".venv", "__pycache__", "*.egg-info", ".pytest_cache", "*.pyc")


def problem(m: Mutation, root: Path = ROOT) -> str | None:
    """Why the entry cannot be applied to the tree at `root` (None: it can)."""
    path = root / m.file
    if not path.is_file():
        return f"{m.file} does not exist"
    n = path.read_text().count(m.old)
    if n != 1:
        return f"{m.file}: the text to break occurs {n} times (must be once): {m.old!r}"
    if "\n" in m.old or "\n" in m.new:
        return "a break is a substitution inside one line"
    missing = [t for t in m.tests if not (root / t).is_file()]
    if missing:
        return f"no test file {', '.join(missing)}"
    return None


def run_one(m: Mutation, work: Path, env: dict) -> tuple[str, float, str]:
    """(verdict, seconds, the first failed test or pytest's last line) for one entry, on a fresh copy at
    work/ahrsd: "caught", "SURVIVED" or "ERROR"."""
    tree = work / "ahrsd"
    if tree.exists():
        shutil.rmtree(tree)
    # copy2 keeps the modification times: numba's cache index checks them (the kernels of an untouched file
    # are loaded, not compiled again)
    shutil.copytree(ROOT, tree, ignore=IGNORED, copy_function=shutil.copy2)
    path = tree / m.file
    text = path.read_text()
    path.write_text(text.replace(m.old, m.new, 1))
    start = time.monotonic()
    proc = subprocess.run([sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *m.tests],
                          cwd=tree, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    took = time.monotonic() - start
    lines = proc.stdout.strip().splitlines() or [""]
    # pytest's exit 1: tests failed (the break was seen: the first failed test is named); 0: all passed; another
    # code (a collection error: a break that does not import, or a test file that does not import on its own; an
    # interrupted run) is no verdict on the tests: ERROR, with pytest's last line
    failed = [line.split()[1] for line in lines if line.startswith("FAILED ")]
    if proc.returncode in (0, 1):
        return ("caught" if proc.returncode else "SURVIVED"), took, (failed[0] if failed else lines[-1])
    return "ERROR", took, f"pytest exit {proc.returncode}: {lines[-1]}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("names", nargs="*", help="entries to run (default: all)")
    ap.add_argument("--list", action="store_true", help="list the entries and stop")
    ap.add_argument("--check", action="store_true", help="only check that every entry still applies")
    ap.add_argument("--tests", action="append", metavar="FILE",
                    help="a test file to run instead of each entry's own (repeat for more)")
    args = ap.parse_args(argv)
    chosen = [m if not args.tests else dataclasses.replace(m, tests=tuple(args.tests))
              for m in MUTATIONS if not args.names or m.name in args.names]
    unknown = set(args.names) - {m.name for m in MUTATIONS}
    if unknown:
        ap.error(f"no entry named {', '.join(sorted(unknown))}")
    if args.list:
        for m in chosen:
            print(f"{m.name:28s} {m.behaviour}")
        return 0
    problems = [f"{m.name}: {p}" for m in chosen if (p := problem(m)) is not None]
    if problems or args.check:
        print("\n".join(problems) or f"all {len(chosen)} entries apply")
        return 1 if problems else 0

    base = Path(tempfile.gettempdir()) / f"ahrsd-mutation-{os.getuid()}"
    base.mkdir(exist_ok=True)
    lock = open(base / "lock", "w")
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        print(f"another mutation run holds {base / 'lock'}", file=sys.stderr)
        return 2
    env = dict(os.environ, PYTHONPATH=str(base), NUMBA_CACHE_DIR=str(base / "numba-cache"),
               AHRSD_SHARED=os.environ.get("AHRSD_SHARED", str(ROOT.parent / "shared")))
    survived, errors = [], []
    try:
        for m in chosen:
            verdict, took, tail = run_one(m, base, env)
            print(f"{verdict:8s} {m.name:28s} {took:6.0f} s  {tail}", flush=True)
            {"SURVIVED": survived, "ERROR": errors}.get(verdict, []).append(m.name)
    finally:
        shutil.rmtree(base / "ahrsd", ignore_errors=True)
    print(f"{len(chosen) - len(survived) - len(errors)} of {len(chosen)} caught"
          + (f"; survived: {', '.join(survived)}" if survived else "")
          + (f"; no verdict (pytest error): {', '.join(errors)}" if errors else ""))
    return 1 if survived or errors else 0


if __name__ == "__main__":
    sys.exit(main())
