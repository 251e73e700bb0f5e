"""A recorded-like sequence of samples with lost ones, invalid axes and the chip's other flags, its counts worked
out one sample at a time by PipelineCounters' rules (daemon.pipeline), the ways to cut it into blocks and a
calibration with every term: what the block-wise reader paths are held to (tests/test_sample_block.py,
tests/test_whole_runs.py)."""

from __future__ import annotations

import numpy as np

from ahrsd.calibration.models import AccelModel, Calibration, GyroModel, MagModel
from ahrsd.core.sample import ImuSample, SampleFlags

RATE_HZ = 819.2
F = SampleFlags


def sequence() -> list[ImuSample]:
    """A recorded-like sequence: 60 samples with lost ones (counter jumps flagged GAP_BEFORE, one at a block's
    first row and one in a block of its own), each invalid flag alone in a block, the chip's other flags
    (ALARM with a DIAG_STAT, STALE, saturation, the burst bug recovered), and clean stretches between."""
    rng = np.random.default_rng(4)
    flags = [SampleFlags.NEW_DATA] * 60
    jumps = {8: 3, 21: 1, 40: 7}                 # index: samples lost before it
    for k in jumps:
        flags[k] |= F.GAP_BEFORE
    flags[13] |= F.MAG_INVALID
    flags[26] |= F.ACCEL_INVALID
    flags[33] |= F.GYRO_INVALID
    flags[47] |= F.GYRO_INVALID | F.ACCEL_INVALID | F.MAG_INVALID | F.GAP_BEFORE
    jumps[47] = 2
    flags[15] = F.STALE
    flags[17] |= F.ALARM
    flags[30] |= F.GYRO_SATURATED | F.BURST_BUG_RECOVERED
    out, counter = [], 1000
    for k, f in enumerate(flags):
        counter += 1 + jumps.get(k, 0)
        out.append(ImuSample(50.0 + counter / RATE_HZ, rng.normal(0, 0.5, 3), rng.normal([0, 0, -9.8], 1.0),
                             rng.normal([20, 0, 40], 3.0), 25.0 + 0.01 * k, 5.0 - 1e-3 * k, f,
                             0x40 if f & F.ALARM else 0, counter))
    return out


def counted_one_by_one(samples: list[ImuSample]) -> tuple[int, int, int, int]:
    """(samples, gaps, lost, invalid) by the rules of PipelineCounters, one sample at a time."""
    gaps = lost = invalid = 0
    last = None
    for s in samples:
        if s.flags & F.GAP_BEFORE:
            gaps += 1
            if last is not None and s.counter > last + 1:
                lost += s.counter - last - 1
        if s.flags & (F.GYRO_INVALID | F.ACCEL_INVALID | F.MAG_INVALID):
            invalid += 1
        last = s.counter
    return len(samples), gaps, lost, invalid


def cuts(n: int, seed: int, max_size: int = 7) -> list[tuple[int, int]]:
    """(lo, hi) blocks of 1 to `max_size` samples covering 0 … n, drawn."""
    rng = np.random.default_rng(seed)
    out, k = [], 0
    while k < n:
        size = int(rng.integers(1, max_size + 1))
        out.append((k, min(n, k + size)))
        k += size
    return out


def calibration(seed: int = 1) -> Calibration:
    """A calibration with every term (the accelerometer's quadratic one too): its rows are a product's."""
    rng = np.random.default_rng(seed)
    return Calibration(GyroModel(rng.normal(0, 0.01, 3), np.eye(3) + rng.normal(0, 0.02, (3, 3))),
                       AccelModel(rng.normal(0, 0.1, 3), np.eye(3) + rng.normal(0, 0.02, (3, 3)),
                                  rng.normal(0, 1e-3, 3)),
                       MagModel(rng.normal(0, 5, 3), np.eye(3) + rng.normal(0, 0.05, (3, 3))))
