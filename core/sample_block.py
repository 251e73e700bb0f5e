"""A block of raw samples kept as columns (what a reader process hands over): the sequence of ImuSamples a
source's `poll()` returns, but each ImuSample is built only when someone asks for it.

The daemon's hot path (daemon.pipeline `process_block`) calibrates the block's vectors at once from the
(n, 3) arrays and builds only the calibrated sample of each row; the raw ImuSamples are built for whoever still
wants them (the vehicle log, a tool that iterates the block), one per row, on demand."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ahrsd.core.sample import ImuSample, SampleFlags

_FLAGS_BY_VALUE: dict[int, SampleFlags] = {}     # SampleFlags(v) goes through the enum machinery (µs a call)


def sample_flags(value: int) -> SampleFlags:
    """SampleFlags(value), from a cache (the flag combinations seen are few; bounded anyway)."""
    flags = _FLAGS_BY_VALUE.get(value)
    if flags is None:
        flags = SampleFlags(value)
        if len(_FLAGS_BY_VALUE) < 4096:
            _FLAGS_BY_VALUE[value] = flags
    return flags


class SampleBlock(Sequence):
    """n raw samples as columns: t_s, temp_c, supply_v, flags (plain ints), diag_stat, counter (sequences) and
    `vectors`, an (n, 9) float64 array of gyro (rad/s), accel (m/s²) and mag (µT) side by side, rows in sample
    order (gyro_rad_s, accel_m_s2, mag_ut are (n, 3) views of it). Indexing builds the ImuSample of a row (its
    vectors are views of the row)."""

    __slots__ = ("t_s", "vectors", "temp_c", "supply_v", "flags", "diag_stat", "counter")

    def __init__(self, t_s: Sequence, vectors: np.ndarray, temp_c: Sequence, supply_v: Sequence, flags: Sequence,
                 diag_stat: Sequence, counter: Sequence):
        self.t_s, self.vectors = t_s, vectors
        self.temp_c, self.supply_v, self.flags, self.diag_stat, self.counter = temp_c, supply_v, flags, diag_stat, counter

    gyro_rad_s = property(lambda self: self.vectors[:, 0:3])     # views made when asked (a slice is not free)
    accel_m_s2 = property(lambda self: self.vectors[:, 3:6])
    mag_ut = property(lambda self: self.vectors[:, 6:9])

    def __len__(self) -> int:
        return len(self.t_s)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(len(self)))]
        r = self.vectors[i]
        return ImuSample(self.t_s[i], r[0:3], r[3:6], r[6:9], self.temp_c[i], self.supply_v[i],
                         sample_flags(self.flags[i]), self.diag_stat[i], self.counter[i])

    def __iter__(self):
        return (self[i] for i in range(len(self)))
