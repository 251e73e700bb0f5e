"""The first start says it is compiling before it compiles (not after), a cached start says nothing,
`ahrsd warm-up` (the unit's ExecStartPre) compiles the configured estimator into the cache, and the announcement's
watcher never looks at numba while numba is still being imported."""

from __future__ import annotations

import logging
import subprocess
import sys
import threading

from ahrsd.cli import warm_up as cli_warm_up


class _Announced(logging.Handler):
    def __init__(self):
        super().__init__()
        self.messages = []
        self.compiling = threading.Event()

    def emit(self, record):
        self.messages.append(record.getMessage())
        if record.getMessage().startswith("compiling"):
            self.compiling.set()


def _handler():
    handler = _Announced()
    logger = logging.getLogger("ahrsd")
    logger.addHandler(handler)
    old = logger.level
    logger.setLevel(logging.INFO)
    return handler, lambda: (logger.removeHandler(handler), logger.setLevel(old))


def test_a_compile_is_announced_while_it_runs():
    handler, restore = _handler()
    seen_during = []

    misses = [0]

    def slow_compile(name):          # a compile: a kernel misses the cache, runs until the announcement is out
        misses[0] += 1
        seen_during.append(handler.compiling.wait(timeout=30))

    try:
        cli_warm_up.compile_estimator("mekf", announce_after_s=0.01, count_compiles=lambda: misses[0],
                                      warm_up=slow_compile)
    finally:
        restore()
    assert seen_during == [True]
    assert handler.messages[0] == ("compiling the mekf estimator (first start after an install or upgrade, "
                                   "cached afterwards) …")
    assert handler.messages[1].startswith("compiled the mekf estimator in ")


def test_a_cached_start_is_silent():
    handler, restore = _handler()
    try:
        cli_warm_up.compile_estimator("mekf", announce_after_s=600.0, warm_up=lambda name: None)
    finally:
        restore()
    assert handler.messages == []


def test_warm_up_command_compiles_the_configured_estimator(tmp_path):
    cfg = tmp_path / "ahrsd.toml"
    cfg.write_text('[estimator]\nname = "mekf"\n')
    r = subprocess.run([sys.executable, "-m", "ahrsd.cli", "warm-up", "--config", str(cfg)], capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("ahrsd warm-up: the mekf estimator is ready in ")
    r = subprocess.run([sys.executable, "-m", "ahrsd.cli", "warm-up", "--estimator", "nonesuch"], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode != 0 and "nonesuch" in r.stderr and "Traceback" not in r.stderr


NUMBA_STATE_PROBE = """
import sys
from ahrsd.cli import warm_up
assert "numba" not in sys.modules, "the probe needs a process that has not imported numba yet"
complete = []

def count_compiles():
    registry = sys.modules.get("numba.core.registry")
    complete.append(registry is not None and hasattr(registry, "CPUDispatcher"))
    return 0

warm_up.compile_estimator("mekf", announce_after_s=0.0, count_compiles=count_compiles)
print(len(complete), all(complete))
"""


def test_the_watcher_never_sees_numba_half_imported():
    """numba imported from two threads at once fails with a circular ImportError (`ahrsd run` died so at load
    17): every look the watcher (and the count before it) takes must find numba's registry complete. Run after
    the warm-up command above, so the mekf kernels load from the cache."""
    r = subprocess.run([sys.executable, "-c", NUMBA_STATE_PROBE], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    looks, all_complete = r.stdout.split()
    assert int(looks) >= 2 and all_complete == "True", r.stdout
