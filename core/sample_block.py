"""A block of raw samples kept as columns (what a reader process hands over): the sequence of ImuSamples a
source's `poll()` returns, but each ImuSample is built only when someone asks for it.

The daemon's hot path (daemon.pipeline `process_block`) calibrates the block's vectors at once from the
(n, 3) arrays and builds only the calibrated sample of each row; the raw ImuSamples are built for whoever still
wants them (the vehicle log, a tool that iterates the block), one per row, on demand. Samples that come built
(a per-sample read, a replay) are put in a block too (`SampleBlock.of`), so the daemon's reader and pipeline
take one kind of input."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ahrsd.core.sample import ImuSample, SampleFlags


class SampleFlagsCache(dict):
    """SampleFlags by flags value, each value made once (SampleFlags(v) goes through the enum machinery on every
    call; the flag combinations seen are few, bounded anyway by `capacity`). A dict whose `__missing__` makes the
    value: a value seen before is a plain dict lookup in C, no Python frame on the per-sample path. `made` counts
    the values made rather than found: what a caller (a test) reads to see the cache at work."""

    __slots__ = ("capacity", "made")

    def __init__(self, capacity: int = 4096):
        super().__init__()
        self.capacity = capacity
        self.made = 0

    def __missing__(self, value: int) -> SampleFlags:
        flags = SampleFlags(value)
        self.made += 1
        if len(self) < self.capacity:
            self[value] = flags
        return flags


SAMPLE_FLAGS = SampleFlagsCache()          # the process's one cache: the readers and the pipeline share it
sample_flags = SAMPLE_FLAGS.__getitem__    # SampleFlags(value), from the cache


class SampleBlock(Sequence):
    """n raw samples as columns: t_s, temp_c, supply_v, flags (plain ints), diag_stat, counter (sequences) and
    `vectors`, an (n, 9) float64 array of gyro (rad/s), accel (m/s²) and mag (µT) side by side, rows in sample
    order (gyro_rad_s, accel_m_s2, mag_ut are (n, 3) views of it). Indexing builds the ImuSample of a row (its
    vectors are views of the row)."""

    __slots__ = ("t_s", "vectors", "temp_c", "supply_v", "flags", "diag_stat", "counter", "_samples")

    def __init__(self, t_s: Sequence, vectors: np.ndarray, temp_c: Sequence, supply_v: Sequence, flags: Sequence,
                 diag_stat: Sequence, counter: Sequence, samples: Sequence[ImuSample] | None = None):
        self.t_s, self.vectors = t_s, vectors
        self.temp_c, self.supply_v, self.flags, self.diag_stat, self.counter = temp_c, supply_v, flags, diag_stat, counter
        self._samples = samples

    @classmethod
    def of(cls, samples: Sequence[ImuSample]) -> "SampleBlock":
        """The block of samples already built (a per-sample read, a replay's or a reader thread's list): its rows
        index those same ImuSample objects."""
        if not samples:
            return cls((), np.empty((0, 9)), (), (), (), (), (), samples)
        # one concatenate and one pass over the samples (a numpy call or a comprehension per column costs more
        # than the pipeline's own work on a sample)
        vectors = np.concatenate([v for s in samples for v in (s.gyro_rad_s, s.accel_m_s2, s.mag_ut)], dtype=np.float64)
        t_s, temp_c, supply_v, flags, diag_stat, counter = zip(*[(s.t_s, s.temp_c, s.supply_v, int(s.flags), s.diag_stat,
                                                                 s.counter) for s in samples])
        return cls(t_s, vectors.reshape(len(samples), 9), temp_c, supply_v, flags, diag_stat, counter, samples)

    gyro_rad_s = property(lambda self: self.vectors[:, 0:3])     # views made when asked (a slice is not free)
    accel_m_s2 = property(lambda self: self.vectors[:, 3:6])
    mag_ut = property(lambda self: self.vectors[:, 6:9])

    def __len__(self) -> int:
        return len(self.t_s)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(len(self)))]
        if self._samples is not None:
            return self._samples[i]
        r = self.vectors[i]
        return ImuSample(self.t_s[i], r[0:3], r[3:6], r[6:9], self.temp_c[i], self.supply_v[i],
                         sample_flags(self.flags[i]), self.diag_stat[i], self.counter[i])

    def __iter__(self):
        return (self[i] for i in range(len(self)))
