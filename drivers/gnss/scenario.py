"""The simulated receiver of a scenario: the GNSS a moving simulated vehicle would carry, as UBX on a pty.

`ScenarioGnssReceiver(scenario, chip_clock)` computes the fixes of `simulation.gnss.GnssSimulator` on the
scenario's exact truth (`SensorStream.truth_at`) and writes each as a UBX NAV-PVT (or NMEA) into a
pseudo-terminal (`simulated.SimulatedGnssReceiver`) when its arrival time (time of validity + the
receiver's latency) comes on `chip_clock` — the simulated chip's own scenario time (`SimulatedAdis16405.now`),
so the fixes and the IMU samples describe the same motion at the same instants. Give `.device` to
`serial_port.SerialGnssSource` with `latency_s = .latency_s`: the daemon then reads it exactly as a receiver
on a UART, and stamps it on the same monotonic clock as the chip's samples.

Faults, on the scenario's time (the chip clock): `outages=[(start_s, stop_s[, reports_no_fix])]` (the
simulator's GnssOutage: silence, or NO_FIX solutions as a u-blox sends when it loses lock) and a glitch every
`glitch_every_s` from the scenario's start: `glitch_kind` "position_jump" or "velocity_spike" of
`glitch_magnitude` m or m/s (None: the simulator's 50 m / 5 m/s), a fix the receiver reports as good that the
estimator's innovation gate must reject, or "nan" (sent as NAV-PVT invalidLlh: the validator rejects it).
"""

from __future__ import annotations

import functools
import math
import threading
import time
from collections.abc import Callable

from .simulated import SimulatedGnssReceiver

LOOKAHEAD_S = 1.0       # fixes computed this far ahead of the chip clock, then written at their arrival time
MAX_WAIT_S = 0.05       # the writer thread re-checks the stop flag at least this often


class ScenarioGnssReceiver:
    """A GnssSimulator on `scenario`'s truth behind a SimulatedGnssReceiver, written in a thread."""

    def __init__(self, scenario: str, chip_clock: Callable[[], float], *, seed: int = 0, rate_hz: float = 5.0,
                 latency_s: float = 0.1, lever_arm_m=(0.0, 0.0, 0.0), protocol: str = "ubx", baud: int = 115200,
                 glitch_every_s: float = 0.0, glitch_kind: str = "position_jump",
                 glitch_magnitude: float | None = None, **simulator_options):
        from ahrsd.simulation import open_stream
        from ahrsd.simulation.gnss import GLITCH_KINDS, GnssGlitch, GnssSimulator

        if not (math.isfinite(glitch_every_s) and glitch_every_s >= 0):
            raise ValueError(f"glitch_every_s must be ≥ 0, got {glitch_every_s!r}")
        if glitch_kind not in GLITCH_KINDS:
            raise ValueError(f"glitch_kind must be one of {', '.join(GLITCH_KINDS)}, got {glitch_kind!r}")

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
        self.glitch_every_s = float(glitch_every_s)
        self._glitch = functools.partial(GnssGlitch, kind=glitch_kind, magnitude=glitch_magnitude)
        if self.glitch_every_s > 0:
            self._glitch(self.glitch_every_s)           # a bad magnitude fails here, not in the thread
        self.fixes_written = 0
        self.fixes_unwritable = 0
        self.fixes_skipped_late = 0
        self.glitches_written = 0
        self.late_skip_s = 1.0 / rate_hz
        self._computed_until_s = self.simulator_start_s = max(0.0, chip_clock())
        self._pending: list = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        # what the writer thread cost (its thread CPU time) and over how long: the simulated receiver's own work,
        # which a real receiver does not take from the host (bench/latency.py reports it apart from the daemon's)
        self.writer_cpu_s = 0.0
        self.writer_wall_s = 0.0

    def start(self) -> "ScenarioGnssReceiver":
        self._thread = threading.Thread(target=self._run, name="sim-gnss-scenario", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        started = time.monotonic()
        while not self._stop.is_set():
            try:
                wait = self.write_due()
            except OSError:                     # the pty was closed under us
                return
            self.writer_cpu_s = time.thread_time()      # this thread's CPU since it started
            self.writer_wall_s = time.monotonic() - started
            self._stop.wait(min(wait, MAX_WAIT_S))

    def write_due(self) -> float:
        """Write every fix whose arrival time has come on the chip clock (what the thread does each time it
        wakes up); return the seconds until the next one is due."""
        now = self.chip_clock()
        while True:
            if not self._pending:
                self._pending = self._fixes_until(now + LOOKAHEAD_S)
                if not self._pending:
                    return MAX_WAIT_S
            fix = self._pending[0]
            wait = fix.extra.get("t_rx_s", fix.t_s + self.latency_s) - now
            if wait > 0:
                return wait
            self._pending.pop(0)
            if -wait > self.late_skip_s:        # this thread was held up: a receiver sends its epochs in time,
                self.fixes_skipped_late += 1    # never a backlog in one burst (they would share one time stamp)
                continue
            try:
                self.receiver.write_fix(fix)
            except (ValueError, TypeError, OverflowError):   # a fix UBX cannot carry
                self.fixes_unwritable += 1
                continue
            self.fixes_written += 1
            self.glitches_written += fix.extra.get("glitch") is not None

    def _fixes_until(self, t_s: float) -> list:
        """The simulator's next fixes, with the periodic glitches near them (the simulator checks each of its
        glitches at every epoch, so it is given only those that can hit the epochs computed now)."""
        if self.glitch_every_s > 0:
            every = self.glitch_every_s
            k0 = max(1, math.floor((self._computed_until_s - 1.0) / every) + 1)
            k1 = math.floor((t_s + 1.0) / every)
            self.simulator.glitches = tuple(self._glitch(k * every) for k in range(k0, k1 + 1))
        self._computed_until_s = max(self._computed_until_s, t_s)
        return self.simulator.fixes_until(t_s)

    def counters(self) -> dict:
        return {"fixes_written": self.fixes_written, "glitches_written": self.glitches_written,
                "fixes_unwritable": self.fixes_unwritable, "fixes_skipped_late": self.fixes_skipped_late,
                "writer_cpu_s": self.writer_cpu_s, "writer_wall_s": self.writer_wall_s}

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        self.receiver.close()
