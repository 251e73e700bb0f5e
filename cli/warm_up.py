"""`ahrsd warm-up`: compile the estimator the configuration selects into numba's on-disk cache, ahead of the
daemon's start (the service unit runs it as `ExecStartPre`), and the announcement both it and `ahrsd run` make
when a compile is under way.

numba compiles a kernel on its first call and caches it (`NUMBA_CACHE_DIR`; the unit points it at the service's
cache directory). A compile takes tens of seconds on a desktop and minutes on a Raspberry Pi (docs/figures.md),
during which nothing else is printed. Loading the cached kernels also takes seconds on a slow or busy computer, so time alone
cannot tell a compile from a cache load: the announcement goes out once a kernel has missed the cache (numba
counts the misses per dispatcher before it compiles) and the warm-up has run for ANNOUNCE_AFTER_S, so a cached
start stays silent however long its loading takes.
"""

from __future__ import annotations

import argparse
import logging
import sys
import threading
import time
from typing import Callable

ANNOUNCE_AFTER_S = 1.0
POLL_S = 0.25

log = logging.getLogger("ahrsd")


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "warm-up", help="compile the estimator into the cache before the daemon starts",
        description="Compile the estimator the configuration selects (numba, cached on disk under NUMBA_CACHE_DIR "
        "or beside the package) so the daemon's next start does not wait for it. The service unit runs it as "
        "ExecStartPre; after an install run it once by hand to check it.")
    p.add_argument("--config", metavar="FILE", help="TOML config (default as `ahrsd run`)")
    p.add_argument("--estimator", metavar="NAME", help="mekf, thesis or ins (default: what the config selects)")
    p.set_defaults(func=run)


def numba_compiles(prefix: str = "ahrsd.") -> int:
    """How many times numba has compiled a disk-cached kernel of the modules under `prefix` in this process
    (its per-dispatcher cache misses: a miss is counted before the compile starts). Kernels without a cache are
    not counted: they compile on every start and are not what the cache saves."""
    # never import here: this runs in a watcher thread while the main thread may be importing numba, and a
    # second thread importing a partly initialised numba fails both imports ("cannot import name ... from
    # partially initialized module"), which ended `ahrsd run` at start-up on a loaded machine
    CPUDispatcher = getattr(sys.modules.get("numba.core.registry"), "CPUDispatcher", None)
    if CPUDispatcher is None:
        return 0

    seen: set[int] = set()
    total = 0
    for name, module in list(sys.modules.items()):
        if not name.startswith(prefix) or module is None:
            continue
        for value in list(vars(module).values()):
            if isinstance(value, CPUDispatcher) and id(value) not in seen:
                seen.add(id(value))
                stats = value.stats
                if stats.cache_path is not None:
                    total += sum(stats.cache_misses.values())
    return total


def estimator_warm_up(name: str) -> None:
    """estimator.warm_up.warm_up, imported when called (numba loads only when something is compiled)."""
    from ahrsd.estimator.warm_up import warm_up

    warm_up(name)


def compile_estimator(name: str, clock=time.monotonic, announce_after_s: float = ANNOUNCE_AFTER_S,
                      count_compiles: Callable[[], int] = numba_compiles,
                      warm_up: Callable[[str], None] = estimator_warm_up) -> float:
    """Run the estimator's warm-up (`warm_up(name)`), saying so while it compiles (a kernel missed the cache and
    `announce_after_s` has passed) and, at the end, that it compiled. Returns the seconds it took."""
    from ahrsd.daemon.estimator_news import estimator_news_muted

    # numba is imported here, in this thread, before the watcher thread looks at it: numba's first import run
    # from two threads at once fails with a circular ImportError in both (the watcher's poll can begin while
    # warm_up is still importing numba: on a slow or loaded board the import alone outlasts ANNOUNCE_AFTER_S)
    import numba.core.registry  # noqa: F401

    started = clock()
    compiles_before = count_compiles()
    done = threading.Event()
    announced = threading.Event()

    def announce_when_compiling() -> None:
        if done.wait(announce_after_s):
            return
        while not done.is_set():
            if count_compiles() > compiles_before:
                announced.set()
                log.info("compiling the %s estimator (first start after an install or upgrade, cached "
                         "afterwards) …", name)
                return
            done.wait(POLL_S)

    watcher = threading.Thread(target=announce_when_compiling, name="warm-up announcement", daemon=True)
    watcher.start()
    try:
        with estimator_news_muted():
            warm_up(name)
    finally:
        done.set()
        watcher.join()
    took = clock() - started
    if announced.is_set() or (took >= announce_after_s and count_compiles() > compiles_before):
        log.info("compiled the %s estimator in %.1f s", name, took)
    return took


def run(args: argparse.Namespace) -> int:
    from ahrsd.daemon.config import Config, ConfigError, default_config_path, load_config

    try:
        path = args.config or default_config_path()
        cfg = load_config(path) if path else Config()
        cfg = cfg.with_overrides(estimator=args.estimator)
    except ConfigError as exc:
        print(f"ahrsd warm-up: error: {exc}", file=sys.stderr)
        return 2
    if logging.getLogger().level > logging.INFO:
        logging.getLogger("ahrsd").setLevel(logging.INFO)
    try:
        took = compile_estimator(cfg.estimator_name)
    except (ValueError, ModuleNotFoundError) as exc:
        print(f"ahrsd warm-up: error: estimator {cfg.estimator_name!r}: {exc}", file=sys.stderr)
        return 1
    from ahrsd.estimator import KERNEL_CACHE_DIR

    print(f"ahrsd warm-up: the {cfg.estimator_name} estimator is ready in {took:.1f} s (cache: {KERNEL_CACHE_DIR})")
    return 0
