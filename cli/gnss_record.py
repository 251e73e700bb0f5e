"""The GNSS half of `ahrsd record`: REC.gnss.csv beside the IMU recording, on the same time base.

Sources: the simulated receiver of a vehicle scenario (`simulation.gnss.GnssSimulator` on the scenario's truth:
its fixes carry the chip's scenario time, shifted to the recording's clock), or a receiver on a serial port
(`drivers.gnss.serial_port.SerialGnssSource`, stamped on the recording's host clock). Fixes are written as they
come: judging them is the validator's, when the recording is replayed (docs/gnss.md, "The recording").
"""

from __future__ import annotations

import math

HEALTH_PERIOD_S = 1.0


class GnssRecorder:
    """Writes the fixes of one GNSS source while `ahrsd record` reads the IMU: call `poll(t_s)` with the time
    of the newest sample after every read, `close()` at the end (returns a one-line summary)."""

    def __init__(self, path, *, simulator=None, time_offset_s: float = 0.0, serial=None):
        from ahrsd.drivers.gnss.recording import GnssRecordingWriter

        self.path = path
        self.simulator = simulator          # simulation.gnss.GnssSimulator (scenario time)
        self.time_offset_s = time_offset_s  # recording clock − scenario time
        self.serial = serial                # drivers.gnss.serial_port.SerialGnssSource (recording clock)
        self.writer = GnssRecordingWriter(path)
        self.written = 0
        self._next_health = -math.inf

    @classmethod
    def for_scenario(cls, path, scenario: str, seed: int, chip_now, recording_clock,
                     lever_arm_m=(0.0, 0.0, 0.0), site=None) -> "GnssRecorder":
        """The simulated receiver of `scenario` (5 Hz, the simulator's default noise and latency), its antenna at
        `lever_arm_m` (body FRD from the IMU, m), its track starting at `site` (a simulation.Site; None: the
        simulator's DEFAULT_SITE), the chip's place."""
        from ahrsd.simulation import GnssSimulator, open_stream

        truth = open_stream(scenario, seed=seed, errors="ideal", site=site)
        t0 = chip_now()
        simulator = GnssSimulator(truth.truth_at, seed=seed, start_s=max(0.0, t0), lever_arm_m=lever_arm_m)
        return cls(path, simulator=simulator, time_offset_s=recording_clock() - t0)

    @classmethod
    def for_serial(cls, path, device: str, baud: int, clock) -> "GnssRecorder":
        from ahrsd.drivers.gnss.serial_port import SerialGnssSource

        return cls(path, serial=SerialGnssSource(device, baud, "auto", clock=clock))

    def poll(self, t_s: float, now: float) -> None:
        """Write what became known by sample time `t_s` (host time `now` for the serial link's health)."""
        if self.simulator is not None:
            import dataclasses

            for fix in self.simulator.fixes_until(t_s - self.time_offset_s):
                self._write(dataclasses.replace(fix, t_s=fix.t_s + self.time_offset_s))
            return
        for fix in self.serial.read_available():
            self._write(fix)
        if now >= self._next_health:
            self._next_health = now + HEALTH_PERIOD_S
            self.serial.poll_health()

    def _write(self, fix) -> None:
        self.writer.write(fix)
        self.written += 1

    def close(self) -> str:
        self.writer.close()
        what = ""
        if self.serial is not None:
            what = f" (link {self.serial.state.value}: {self.serial.status_message})"
            self.serial.close()
        return f"wrote {self.written} GNSS fixes to {self.path}{what}"
