"""A test's daemon on a thread of the test's process: the `Service` a set-up script builds, run by `Service.run`
(which skips its signal handlers off the main thread). No interpreter, imports and kernel loads of a daemon process
of its own, for a test whose check is what the daemon sends and does, not its process (tests/test_magcal_field_daemon.py,
tests/test_magcal_integration.py's MAVProxy session; the daemon as a process: test_magcal_integration's pymavlink
session with its restart). Its log (the `ahrsd` loggers at INFO, as the daemon's own) goes to a file while it runs."""

from __future__ import annotations

import asyncio
import logging
import multiprocessing
import threading
import time
from pathlib import Path


class ThreadDaemon:
    """`script` (which sets up a `Service` named `service`, reading its arguments from `a`) and then
    `service.run()` on a thread of this process. `stop` stops it as SIGTERM would, waits for it, and reaps the
    processes it spawned (the fit worker), so that their CPU is counted with the test's; a second call does nothing."""

    def __init__(self, script: str, args: dict, log_path: Path):
        self.script = script
        self.handler = logging.FileHandler(log_path)
        self.handler.setFormatter(logging.Formatter("%(asctime)s %(name)s: %(message)s"))
        self.logger = logging.getLogger("ahrsd")
        self.level = self.logger.level
        self.logger.setLevel(logging.INFO)
        self.logger.addHandler(self.handler)
        self.namespace = {"a": args, "__name__": "thread_daemon"}
        self.failure: BaseException | None = None
        self.stopped = False                 # stop has run: its log handler is off the `ahrsd` logger
        self.thread = threading.Thread(target=self._run, name="thread-daemon", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        try:
            exec(compile(self.script, "thread_daemon", "exec"), self.namespace)
            asyncio.run(self.namespace["service"].run())
        except BaseException as exc:  # noqa: BLE001 - said by stop, in the test's thread
            self.failure = exc

    def stop(self, timeout_s: float = 60.0) -> None:
        if self.stopped:                     # a test's stop, then its fixture's
            return
        try:
            end = time.monotonic() + timeout_s
            while self.thread.is_alive() and time.monotonic() < end and getattr(
                    self.namespace.get("service"), "loop", None) is None:
                time.sleep(0.05)                                 # a stop asked for before the loop runs
            service = self.namespace.get("service")
            if service is not None and service.loop is not None and self.thread.is_alive():
                service.loop.call_soon_threadsafe(service.request_stop, 0)
            self.thread.join(max(0.0, end - time.monotonic()))
            for child in multiprocessing.active_children():     # the fit worker, shut down by the stop
                child.join(timeout_s)
        finally:
            self.stopped = True
            self.logger.removeHandler(self.handler)
            self.logger.setLevel(self.level)
            self.handler.close()
        assert not self.thread.is_alive(), "the daemon did not stop"
        assert self.failure is None, repr(self.failure)
