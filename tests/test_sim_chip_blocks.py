"""A free-running simulated chip on a named scenario computes its samples in blocks of FREE_RUNNING_BLOCK_SAMPLES
(drivers/simulated.py: fewer blocks, less fixed cost per sample for `ahrsd record --seconds` and the tests): its
burst frames must be byte for byte those of the chip with BLOCK_SAMPLES-sample blocks, across the block edges
(the averaging filter's history and the simulation's random processes run on), at the default filter and at a
longer one. A stream object a caller gives keeps BLOCK_SAMPLES (tests/sim_streams.FixedStream's values change
per block)."""

from __future__ import annotations

import numpy as np
import pytest

from ahrsd.drivers import registers as R
from ahrsd.drivers import simulated
from ahrsd.drivers.simulated import SimulatedAdis16405
from sim_streams import FixedStream

BURST_TX = R.BURST_COMMAND + bytes(R.BURST_DATA_BYTES)
SAMPLES = 5000          # over two 2048-sample blocks and nineteen 256-sample ones


def _bursts(scenario: str, seed: int, sens_avg: int | None) -> bytes:
    chip = SimulatedAdis16405(scenario, seed=seed)
    if sens_avg is not None:                          # SENS_AVG written as the driver writes it: two byte writes
        for frame in R.write_frames(R.SENS_AVG, sens_avg):
            chip.transfer(frame, R.SPI_SLOW_HZ)
    return b"".join(chip.transfer(BURST_TX, R.SPI_BURST_HZ) for _ in range(SAMPLES))


@pytest.mark.parametrize("scenario, seed, sens_avg", [("boat", 3, None), ("tumble", 5, 0x0406)])
def test_the_free_running_chips_frames_do_not_depend_on_the_block_length(monkeypatch, scenario, seed, sens_avg):
    assert simulated.FREE_RUNNING_BLOCK_SAMPLES > simulated.BLOCK_SAMPLES
    long_blocks = _bursts(scenario, seed, sens_avg)
    monkeypatch.setattr(simulated, "FREE_RUNNING_BLOCK_SAMPLES", simulated.BLOCK_SAMPLES)
    short_blocks = _bursts(scenario, seed, sens_avg)
    assert len(long_blocks) == SAMPLES * len(BURST_TX)
    frames = np.frombuffer(long_blocks, np.uint8).reshape(SAMPLES, -1)
    assert len(np.unique(frames[:, 4:6], axis=0)) > 50           # the gyro's X word moves: not a constant output
    first_diff = next((k for k in range(SAMPLES) if long_blocks[k * len(BURST_TX):(k + 1) * len(BURST_TX)]
                       != short_blocks[k * len(BURST_TX):(k + 1) * len(BURST_TX)]), None)
    assert first_diff is None, f"frame {first_diff} differs"


def test_a_callers_stream_is_pulled_in_blocks_of_block_samples():
    sizes = []

    class Counting(FixedStream):
        def next_block(self, n):
            sizes.append(n)
            return super().next_block(n)

    chip = SimulatedAdis16405(Counting())
    for _ in range(3 * simulated.BLOCK_SAMPLES):
        chip.transfer(BURST_TX, R.SPI_BURST_HZ)
    assert sizes and set(sizes) == {simulated.BLOCK_SAMPLES}
