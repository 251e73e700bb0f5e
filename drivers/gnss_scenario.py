"""The simulated receiver of a scenario: the GNSS a moving simulated vehicle would carry, as UBX on a pty.

`ScenarioGnssReceiver(scenario, chip_clock)` computes the fixes of `simulation.gnss.GnssSimulator` on the
scenario's exact truth (`SensorStream.truth_at`) and writes each as a UBX NAV-PVT (or NMEA) into a
pseudo-terminal (`gnss_simulated.SimulatedGnssReceiver`) when its arrival time (time of validity + the
receiver's latency) comes on `chip_clock` — the simulated chip's own scenario time (`SimulatedAdis16405.now`),
so the fixes and the IMU samples describe the same motion at the same instants. Give `.device` to
`gnss_serial.SerialGnssSource` with `latency_s = .latency_s`: the daemon then reads it exactly as a receiver
on a UART, and stamps it on the same monotonic clock as the chip's samples.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from .gnss_simulated import SimulatedGnssReceiver

LOOKAHEAD_S = 1.0       # fixes computed this far ahead of the chip clock, then written at their arrival time
MAX_WAIT_S = 0.05       # the writer thread re-checks the stop flag at least this often


class ScenarioGnssReceiver:
    """A GnssSimulator on `scenario`'s truth behind a SimulatedGnssReceiver, written in a thread."""

    def __init__(self, scenario: str, chip_clock: Callable[[], float], *, seed: int = 0, rate_hz: float = 5.0,
                 latency_s: float = 0.1, lever_arm_m=(0.0, 0.0, 0.0), protocol: str = "ubx", baud: int = 115200,
                 **simulator_options):
        from ahrsd.simulation import open_stream
        from ahrsd.simulation.gnss import GnssSimulator

        truth = open_stream(scenario, seed=seed, errors="ideal")
        # epochs from now on: a receiver switched on does not deliver the fixes of the time before
        self.simulator = GnssSimulator(truth.truth_at, rate_hz=rate_hz, seed=seed, latency_s=latency_s,
                                       lever_arm_m=lever_arm_m, start_s=max(0.0, chip_clock()),
                                       **simulator_options)
        self.chip_clock = chip_clock
        self.latency_s = float(latency_s)
        self.baud = int(baud)
        self.receiver = SimulatedGnssReceiver((), protocol=protocol, baud=baud, clock=chip_clock, seed=seed)
        self.device = self.receiver.device
        self.fixes_written = 0
        self.fixes_unwritable = 0
        self.fixes_skipped_late = 0
        self.late_skip_s = 1.0 / rate_hz
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> "ScenarioGnssReceiver":
        self._thread = threading.Thread(target=self._run, name="sim-gnss-scenario", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        pending: list = []
        while not self._stop.is_set():
            if not pending:
                pending = self.simulator.fixes_until(self.chip_clock() + LOOKAHEAD_S)
                if not pending:
                    self._stop.wait(MAX_WAIT_S)
                    continue
            fix = pending[0]
            wait = fix.extra.get("t_rx_s", fix.t_s + self.latency_s) - self.chip_clock()
            if wait > 0:
                self._stop.wait(min(wait, MAX_WAIT_S))
                continue
            pending.pop(0)
            if -wait > self.late_skip_s:        # this thread was held up: a receiver sends its epochs in time,
                self.fixes_skipped_late += 1    # never a backlog in one burst (they would share one time stamp)
                continue
            try:
                self.receiver.write_fix(fix)
            except OSError:                     # the pty was closed under us
                return
            except (ValueError, TypeError, OverflowError):   # a fix UBX cannot carry (an outage's NaN)
                self.fixes_unwritable += 1
                continue
            self.fixes_written += 1

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        self.receiver.close()
