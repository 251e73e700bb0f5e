""""compiling the … estimator" is said only when numba compiles, never for a slow load from the cache (on a busy
or slow computer loading the cached kernels takes seconds, and the old one-second timer then claimed a compile on
every start), and `numba_compiles` counts real numba cache misses."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import textwrap
import time

from ahrsd.cli import warm_up as cli_warm_up


def _messages(warm_up, count_compiles):
    seen = []

    class Collect(logging.Handler):
        def emit(self, record):
            seen.append(record.getMessage())

    handler = Collect()
    logger = logging.getLogger("ahrsd")
    old = logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    try:
        cli_warm_up.compile_estimator("mekf", announce_after_s=0.01, count_compiles=count_compiles, warm_up=warm_up)
    finally:
        logger.removeHandler(handler)
        logger.setLevel(old)
    return seen


def test_a_slow_cache_load_is_not_announced_as_a_compile():
    # 0.4 s of loading with the announcement due after 0.01 s: no kernel missed the cache, so nothing is said
    assert _messages(lambda name: time.sleep(0.4), lambda: 7) == []


def test_a_compile_that_starts_late_is_announced_once():
    misses = [3]

    def load_then_compile(name):      # some kernels load from the cache, then one misses and compiles
        time.sleep(0.1)
        misses[0] += 1
        time.sleep(0.6)

    seen = _messages(load_then_compile, lambda: misses[0])
    assert len(seen) == 2 and seen[0].startswith("compiling the mekf estimator (")
    assert seen[1].startswith("compiled the mekf estimator in ")


KERNEL = '''
import numba

@numba.njit(cache=True)
def twice(x):
    return 2.0 * x

@numba.njit
def thrice(x):          # no disk cache: not counted
    return 3.0 * x
'''

COUNT = '''
import sys
sys.path.insert(0, sys.argv[1])
from ahrsd.cli.warm_up import numba_compiles
import warm_up_probe_kernel as k
before = numba_compiles("warm_up_probe_")
k.twice(1.0); k.thrice(1.0)
print(before, numba_compiles("warm_up_probe_"))
'''


def test_numba_compiles_counts_cache_misses_of_cached_kernels_only(tmp_path):
    (tmp_path / "warm_up_probe_kernel.py").write_text(textwrap.dedent(KERNEL))
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    runs = [subprocess.run([sys.executable, "-c", COUNT, str(tmp_path)], capture_output=True, text=True, env=env,
                           timeout=300) for _ in range(2)]
    for r in runs:
        assert r.returncode == 0, r.stderr
    assert runs[0].stdout.split() == ["0", "1"]       # empty cache: `twice` compiled (`thrice` not counted)
    assert runs[1].stdout.split() == ["0", "0"]       # the second process loads `twice` from the cache
