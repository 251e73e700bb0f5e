"""The `ahrsd` console script: one entry point, one subcommand per job.

Each subcommand lives in its own module `ahrsd.cli.<name>` exposing `register(subparsers) -> None`, which
adds its parser and sets `func(args) -> int`. Those modules import their heavy dependencies inside `func`, so
`ahrsd --help` stays fast.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from typing import NoReturn

from ahrsd.cli import calibrate, log, magcal, record, replay, run, warm_up

# Order is the order shown in `ahrsd --help`.
SUBCOMMANDS = (run, record, replay, calibrate, magcal, log, warm_up)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ahrsd",
        description="ADIS16405 AHRS companion daemon: attitude and true heading over MAVLink, "
        "with bench and field magnetometer calibration.",
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    parser.add_argument("--version", action="version", version=f"ahrsd {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module in SUBCOMMANDS:
        module.register(sub)
    return parser


def console_main() -> None:
    """The `ahrsd` console script and `python -m ahrsd.cli`: main(), then the process's exit (tests call main()).

    After `ahrsd run`'s daemon has stopped, with nothing of it left running (no thread but this one, no child
    process: the sensor reader, the log writers and their files were closed and joined by the stop), the process
    ends with os._exit once the log handlers are flushed. What the interpreter's teardown would still do is free
    memory that the exit frees anyway, and once the estimator's compiled kernels are loaded that costs a good
    part of a daemon start's CPU (docs/daemon.md "Stopping"), which every daemon a test starts pays."""
    from ahrsd.cli import run as run_command

    code = main()
    if run_command.daemon_stopped:
        exit_stopped_daemon(code)
    sys.exit(code)


def exit_stopped_daemon(code: int) -> NoReturn:
    """The end of a process whose daemon (`Service.run()`) has returned: os._exit(code) once the log handlers
    are flushed when nothing of it is left running, else sys.exit(code) (console_main; a script that runs a
    Service of its own, as the mag-cal integration tests do, ends the same way)."""
    if _nothing_left_running(ENDING_WAIT_S):
        logging.shutdown()      # flushes and closes the log's handlers, as the interpreter's exit would
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        os._exit(code)
    sys.exit(code)


# How long the exit waits for what the stop has already told to end: the field calibration's fit worker, shut
# down without waiting by the daemon's stop (daemon/magcal.py), ends with its manager thread once its process
# has exited (its own interpreter's exit: seconds on a loaded machine). The interpreter's exit would wait for
# them too, so the wait delays nothing; what is still alive after it is left to that exit.
ENDING_WAIT_S = 5.0


def _nothing_left_running(wait_s: float = 0.0) -> bool:
    """No thread but this one and no child process, once the child processes and non-daemon threads still alive
    have had up to wait_s to end."""
    import threading
    import time

    deadline = time.monotonic() + wait_s
    multiprocessing = sys.modules.get("multiprocessing")
    for child in multiprocessing.active_children() if multiprocessing is not None else ():
        child.join(max(0.0, deadline - time.monotonic()))
    for thread in threading.enumerate():
        if thread is not threading.current_thread() and not thread.daemon:   # what the interpreter's exit joins
            thread.join(max(0.0, deadline - time.monotonic()))
    if threading.active_count() > 1:
        return False
    return multiprocessing is None or not multiprocessing.active_children()


def main(argv: list[str] | None = None) -> int:
    try:
        return _main(argv)
    except KeyboardInterrupt:
        # said, so a replay or calibration stopped by Ctrl-C is not taken for one that ended (its output is not
        # written); 130 = 128 + SIGINT, what a shell reports
        command = next((a for a in (argv if argv is not None else sys.argv[1:]) if not a.startswith("-")), None)
        print(f"\n{' '.join(filter(None, ('ahrsd', command)))}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # `ahrsd calibrate ... | head`: the reader went away. Exit quietly like other Unix tools (no traceback);
        # stdout is pointed at /dev/null so the interpreter's final flush cannot raise again.
        _silence_stdout()
        return 141   # 128 + SIGPIPE, what a shell reports for a tool killed by the signal


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    # Before the command imports anything of its own: the estimator package points numba's cache at the
    # directory keyed by the kernels' sources (estimator/kernel_cache.py), which a kernel outside the estimator
    # (calibration/allan/irls.py) must also find set when it is defined. Here, not at the top of this module:
    # every process multiprocessing spawns from the `ahrsd` script imports this module again, and needs neither.
    import ahrsd.estimator  # noqa: F401
    return int(args.func(args) or 0)


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("ahrsd")
    except PackageNotFoundError:
        return "(not installed)"


def _silence_stdout() -> None:
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):
        pass


if __name__ == "__main__":
    console_main()
