"""A test's SPI bus in front of the simulated ADIS16405 (drivers.simulated.SimulatedAdis16405): it passes on each
member the driver and `ahrsd record --sim` use, declared here once (no forwarding of whatever is asked): the bus
(drivers.spi.SpiBus: transfer, sleep, close), the chip's clock (`now`) and what drivers.ground_truth's burst taps
note at each burst (`sample_index`, `output_truth_q_wxyz`), and the chip's counters (`stats`). A fake subclasses
it and overrides what it changes (usually `transfer`)."""

from __future__ import annotations


class SimulatedChipBus:
    def __init__(self, chip):
        self.chip = chip

    def transfer(self, tx: bytes, speed_hz: int, delay_us: int = 0) -> bytes:
        return self.chip.transfer(tx, speed_hz, delay_us)

    def sleep(self, seconds: float) -> None:
        self.chip.sleep(seconds)

    def close(self) -> None:
        self.chip.close()

    def now(self) -> float:
        return self.chip.now()

    stats = property(lambda self: self.chip.stats)
    sample_index = property(lambda self: self.chip.sample_index)
    output_truth_q_wxyz = property(lambda self: self.chip.output_truth_q_wxyz)
