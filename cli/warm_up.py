"""`ahrsd warm-up`: compile the estimator the configuration selects into numba's on-disk cache, ahead of the
daemon's start (the service unit runs it as `ExecStartPre`), and the announcement both it and `ahrsd run` make
when a compile is under way.

numba compiles a kernel on its first call and caches it (`NUMBA_CACHE_DIR`; the unit points it at the service's
cache directory). A compile takes 15–40 s on a desktop and several times that on a Raspberry Pi, during which
nothing else is printed: the announcement goes out when the warm-up has not finished after ANNOUNCE_AFTER_S, so a
cached start (under a second) stays silent.
"""

from __future__ import annotations

import argparse
import logging
import threading
import time

ANNOUNCE_AFTER_S = 1.0

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


def compile_estimator(name: str, clock=time.monotonic, announce_after_s: float = ANNOUNCE_AFTER_S) -> float:
    """Run the estimator's warm-up (estimator.warm_up), saying so first when it takes longer than
    `announce_after_s` (a compile, not a cache load). Returns the seconds it took."""
    from ahrsd.estimator.warm_up import warm_up

    started = clock()
    announced = threading.Event()

    def announce() -> None:
        announced.set()
        log.info("compiling the %s estimator (first start only, cached afterwards) …", name)

    timer = threading.Timer(announce_after_s, announce)
    timer.daemon = True
    # the throwaway estimator's own news ("velocity and position set from the GNSS fix at t=0.000 s") is not the
    # daemon's: below WARNING it is kept out of the log while it runs
    estimator_log = logging.getLogger("ahrsd.estimator")
    level = estimator_log.level
    estimator_log.setLevel(max(level, logging.WARNING))
    timer.start()
    try:
        warm_up(name)
    finally:
        timer.cancel()
        estimator_log.setLevel(level)
    took = clock() - started
    if announced.is_set():
        log.info("compiled the %s estimator in %.1f s", name, took)
    return took


def run(args: argparse.Namespace) -> int:
    import sys

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
