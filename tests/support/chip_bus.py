"""A test's SPI bus in front of the simulated ADIS16405 (drivers.simulated.SimulatedAdis16405): the bus and clock
the driver and `ahrsd record --sim` use, passed on by drivers.ground_truth.ChipBus (transfer, sleep, close, now),
plus what drivers.ground_truth's burst taps note at each burst (`sample_index`, `output_truth_q_wxyz`) and the
chip's counters (`stats`), declared here once (no forwarding of whatever is asked). A fake subclasses it and
overrides what it changes (usually `transfer`)."""

from __future__ import annotations

from ahrsd.drivers.ground_truth import ChipBus


class SimulatedChipBus(ChipBus):
    stats = property(lambda self: self.chip.stats)
    sample_index = property(lambda self: self.chip.sample_index)
    output_truth_q_wxyz = property(lambda self: self.chip.output_truth_q_wxyz)
