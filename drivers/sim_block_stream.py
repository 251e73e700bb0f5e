"""Where the simulated ADIS16405 (drivers.simulated) takes its samples from: a stream of blocks, and the block.

A simulation stream (`ahrsd.simulation.open_stream`, or a test's of the same shape) is computed either in the
chip's own process (`InProcessStream` here) or ahead in a producer process of its own
(drivers.sim_block_producer.ProducedStream). The chip asks both the same members (`BlockStream`) and gets the
same `ChipBlock` from both, so it never asks which kind it reads.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

log = logging.getLogger(__name__)


@dataclass
class ChipBlock:
    """What the simulated chip takes from a stream block: the sensor values and, where the stream knows it, the
    truth attitude (body→NED, scalar first) and body rate of each sample (None where it does not)."""

    t_s: np.ndarray
    gyro_rad_s: np.ndarray
    accel_m_s2: np.ndarray
    mag_ut: np.ndarray
    temp_c: np.ndarray
    truth_q_wxyz: np.ndarray | None
    truth_gyro_rad_s: np.ndarray | None

    @classmethod
    def of(cls, block) -> "ChipBlock":
        """A simulation stream's block (`ahrsd.simulation.SensorBlock`, or a test stream's of its shape)."""
        return cls(block.t_s, block.gyro_rad_s, block.accel_m_s2, block.mag_ut, block.temp_c, block.truth_q_wxyz,
                   block.truth_gyro_rad_s)

    def columns(self) -> dict[str, np.ndarray | None]:
        """Each field by name (the producer's shared-memory columns, drivers.sim_block_producer.COLUMNS)."""
        return {"t_s": self.t_s, "gyro_rad_s": self.gyro_rad_s, "accel_m_s2": self.accel_m_s2,
                "mag_ut": self.mag_ut, "temp_c": self.temp_c, "truth_q_wxyz": self.truth_q_wxyz,
                "truth_gyro_rad_s": self.truth_gyro_rad_s}


@runtime_checkable
class SimulationStream(Protocol):
    """A simulation stream: `ahrsd.simulation.SensorStream`, or a test's (tests/sim_streams.py). Its blocks
    have the fields of `ChipBlock`."""

    def next_block(self, n: int): ...


class BlockStream(Protocol):
    """What the chip asks of the stream it reads, whichever kind."""

    computed_elsewhere: bool    # the blocks are made ahead in another process: a wait is that process short of CPU
    pid: int | None             # that process (a real-time reader shares its priority with it), None: this process
    waited_s: float             # how long the last next_block waited for it (0 for a stream computed here)

    def next_block(self, n: int) -> ChipBlock: ...

    def restart(self, rate_hz: float, start_s: float) -> None:
        """The chip's rate changed (SMPL_PRD written): the blocks from now on are at `rate_hz`, from `start_s`
        of the scenario, where the stream can follow a rate."""

    def close(self) -> None: ...


class InProcessStream:
    """A simulation stream computed in the chip's own process.

    stream: the simulation stream now read. reopen(rate_hz, start_s): a new one at another rate (None: a ready
    stream, which keeps its own sample spacing whatever the chip's rate). ahead: compute the next block in a
    helper thread while the chip reads this one (a chip on a real-time clock: the simulator takes milliseconds
    per block, and computed inside a read it would make that read late and lose chip samples the real part,
    computing in silicon, would not lose).
    """

    computed_elsewhere = False
    pid = None
    waited_s = 0.0

    def __init__(self, stream: SimulationStream, reopen: Callable[[float, float], SimulationStream] | None,
                 ahead: bool):
        self._stream = stream
        self._reopen = reopen
        self._ahead = ahead
        self._prefetcher = None
        self._prefetched = None         # the next block of self._stream, being computed
        self._blocks_given = 0

    def next_block(self, n: int) -> ChipBlock:
        self._blocks_given += 1
        if not self._ahead:
            return ChipBlock.of(self._stream.next_block(n))
        if self._prefetched is not None:
            blk = self._prefetched.result()
        else:
            blk = self._stream.next_block(n)
        if self._prefetcher is None:
            from concurrent.futures import ThreadPoolExecutor

            self._prefetcher = ThreadPoolExecutor(1, thread_name_prefix="sim-adis16405-blocks")
        self._prefetched = self._prefetcher.submit(self._stream.next_block, n)
        return ChipBlock.of(blk)

    def restart(self, rate_hz: float, start_s: float) -> None:
        if self._reopen is not None:
            self._stream = self._reopen(rate_hz, start_s)
            self._prefetched = None          # a block of the old stream's
        elif self._blocks_given:
            log.warning("fixed stream: rate change to %.3f SPS keeps the stream's own sample spacing", rate_hz)

    def close(self) -> None:
        if self._prefetcher is not None:
            self._prefetcher.shutdown(wait=False, cancel_futures=True)
            self._prefetcher = None
