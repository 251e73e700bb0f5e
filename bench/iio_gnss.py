"""The GNSS receiver of the vehicle a simulated IIO device carries (drivers.simulated_iio), for bench/latency.py
`--sensor iio --gnss on`: the scenario's simulated receiver (drivers.gnss.scenario, UBX NAV-PVT at 5 Hz on a
pty) on the chip's own time, so that its fixes and the kernel's records describe the same motion at the same
instants, and the daemon reads it with `[gnss] source = "serial"`, as a receiver on a UART beside the kernel's
IIO driver on hardware.

Why not `ahrsd run --gnss-sim`: that receiver follows the daemon's own simulated chip (`[sensor] source = "sim"`,
daemon.config refuses it with any other sensor); with IIO the chip runs in the simulated kernel's process, and
only its time origin (`SimulatedIioDevice.chip_time_s`) ties the receiver to it. The receiver runs in a process
of its own (spawned): a real receiver takes nothing from the host, so its CPU is reported apart from the
daemon's (`pid`), not inside it.

    rx = IioGnssReceiver(device, "boat")        # device: a SimulatedIioDevice, up (wait_ready)
    ... [gnss] source = "serial", device = rx.device, protocol = "ubx", latency_s = rx.latency_s ...
    rx.counters(); rx.close()
"""

from __future__ import annotations

import multiprocessing
import time

_COUNTERS = ("fixes_written", "fixes_skipped_late", "fixes_unwritable")


class IioGnssReceiver:
    """The receiver process; `device` and `latency_s` for the daemon's [gnss] table."""

    def __init__(self, device, scenario: str, *, seed: int = 0, timeout_s: float = 120.0):
        ctx = multiprocessing.get_context("spawn")
        self._counts = ctx.Array("q", len(_COUNTERS), lock=False)
        self._stop = ctx.Event()
        parent, child = ctx.Pipe(duplex=False)
        # the chip's time 0 on CLOCK_MONOTONIC (one clock for every process): chip time = monotonic − origin
        origin_s = time.monotonic() - device.chip_time_s()
        self._proc = ctx.Process(target=_serve, name="sim-iio-gnss", daemon=True,
                                 args=(scenario, seed, origin_s, child, self._counts, self._stop))
        self._proc.start()
        child.close()
        if not parent.poll(timeout_s):
            self.close()
            raise RuntimeError("the simulated receiver's process did not start")
        self.device, self.latency_s, self.baud = parent.recv()

    @property
    def pid(self) -> int | None:
        return self._proc.pid

    def counters(self) -> dict:
        return {k: int(self._counts[i]) for i, k in enumerate(_COUNTERS)}

    def close(self) -> None:
        self._stop.set()
        self._proc.join(5.0)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join(1.0)


def _serve(scenario: str, seed: int, origin_s: float, conn, counts, stop) -> None:
    """The receiver process: ScenarioGnssReceiver on the chip's time, its counters shared until stopped."""
    import signal

    from ahrsd.drivers.gnss.scenario import ScenarioGnssReceiver

    signal.signal(signal.SIGINT, signal.SIG_IGN)          # the bench or test ends it
    rx = ScenarioGnssReceiver(scenario, chip_clock=lambda: time.monotonic() - origin_s, seed=seed).start()
    conn.send((rx.device, rx.latency_s, rx.baud))
    conn.close()
    try:
        while not stop.wait(0.2):
            for i, k in enumerate(_COUNTERS):
                counts[i] = getattr(rx, k)
    finally:
        for i, k in enumerate(_COUNTERS):
            counts[i] = getattr(rx, k)
        rx.close()
