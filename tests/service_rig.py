"""Test helpers shared by the in-process service tests and the subprocess integration tests.

An in-process `Service` started on its own event loop (no sensor reader task), whose only endpoint sends to a
UDP socket the test reads; free loopback ports; stopping a subprocess politely, then firmly.
"""

from __future__ import annotations

import asyncio
import dataclasses
import signal
import socket
import subprocess
import time

from ahrsd.daemon.config import Config, EndpointConfig, StateConfig
from ahrsd.daemon.service import Service
from ahrsd.drivers.source_interface import LiveSource


class DummySource(LiveSource):
    """A sensor source that never delivers: the tests drive the MAVLink side only."""

    description = "no sensor (test harness)"
    sample_rate_hz = 819.2
    per_sample = True

    def read_one(self, now):
        return None

    def next_read_time(self):
        return 0.0

    def poll(self):
        return []

    def counters(self):
        return {}

    def close(self):
        pass


def free_udp_port() -> int:
    """A UDP port the OS says is free on 127.0.0.1."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def gcs_socket(rcvbuf: int | None = None) -> socket.socket:
    """A non-blocking UDP socket on a free loopback port, standing in for a ground station."""
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(("127.0.0.1", 0))
    gcs.setblocking(False)
    if rcvbuf:
        gcs.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    return gcs


def start_service(gcs: socket.socket, state_dir, **config_changes) -> tuple[Service, asyncio.AbstractEventLoop]:
    """A Service whose only endpoint sends to `gcs`, started (endpoints open, no reader task) on a new loop."""
    return start_service_on((EndpointConfig(f"udpout:127.0.0.1:{gcs.getsockname()[1]}"),), state_dir,
                            **config_changes)


def start_service_on(endpoints, state_dir, *, clock=time.monotonic, warm_fit_worker=True,
                     **config_changes) -> tuple[Service, asyncio.AbstractEventLoop]:
    """A Service with these endpoints, started (endpoints open, no reader task) on a new loop; `clock`: the
    daemon's clock (a test steps it); `warm_fit_worker`: the field calibration's (Service)."""
    cfg = dataclasses.replace(Config(), endpoints=tuple(endpoints), state=StateConfig(str(state_dir)),
                              **config_changes)
    service = Service(cfg, source=DummySource(), clock=clock, warm_fit_worker=warm_fit_worker)
    loop = asyncio.new_event_loop()

    async def start():
        service.loop = asyncio.get_running_loop()
        service._stop = asyncio.Event()
        service.start()

    loop.run_until_complete(start())
    return service, loop


def stop_service(service: Service, loop: asyncio.AbstractEventLoop) -> None:
    """Cancel the service's tasks, close its endpoints and the loop."""
    for t in asyncio.all_tasks(loop):
        t.cancel()
    loop.run_until_complete(asyncio.sleep(0.01))
    if service.endpoints and service.endpoints[0].conn is not None:
        service.shutdown_io("test end")
    loop.close()


def stop_process(proc: subprocess.Popen, timeout_s: float = 10.0) -> None:
    """SIGTERM, wait, then SIGKILL if it did not stop in time."""
    if proc.poll() is not None:
        return
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
