"""The simulated backend: the scenario's receiver (scenario.py) writing UBX into a pty, read by the serial
backend (serial_port.py) exactly as a receiver on a UART: simulated hardware takes the hardware's path, byte
for byte. This class only owns the pair: it starts the receiver's writer and closes both."""

from __future__ import annotations

from collections.abc import Callable

from .backend import GnssBackend, GnssHealth
from .scenario import ScenarioGnssReceiver
from .serial_port import SerialGnssSource
from ahrsd.core.gnss import GnssFix


class SimulatedGnssBackend(GnssBackend):
    """`receiver` (not started) and the serial backend on its pty, stamped on `clock` (the samples' clock).
    writer_thread=False: `start` starts no writer; whoever steps the clock calls `receiver.write_due()` (a test
    on simulated time)."""

    def __init__(self, receiver: ScenarioGnssReceiver, clock: Callable[[], float], description: str = "", *,
                 writer_thread: bool = True):
        self.receiver = receiver
        self.writer_thread = writer_thread
        self.port = SerialGnssSource(receiver.device, receiver.baud, "ubx", latency_s=receiver.latency_s,
                                     clock=clock)
        self.description = description or f"simulated receiver (UBX on {receiver.device})"

    def start(self) -> None:
        if self.writer_thread:
            self.receiver.start()

    def read(self) -> list[GnssFix]:
        return self.port.read()

    def fileno(self) -> int:
        return self.port.fileno()

    def health(self) -> GnssHealth:
        return self.port.health()

    def stats(self) -> dict[str, dict]:
        return {**self.port.stats(), "sim_receiver": self.receiver.counters()}

    def close(self) -> None:
        try:
            self.port.close()
        finally:
            self.receiver.close()
