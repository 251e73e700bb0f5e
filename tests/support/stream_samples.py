"""A simulated stream's samples as the daemon's reader gets them (counter = index, NEW_DATA), simulated and built
once for a test module that feeds the same stream to several services: the simulator and `make_sample` cost more
than some of the runs that read them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ahrsd.core.sample import ImuSample, SampleFlags, make_sample
from ahrsd.simulation import open_stream
from ahrsd.simulation.errors import SensorErrors

BLOCK = 4096        # next_block's size: the tests read the stream this way before, and the stream is the same


@dataclass(frozen=True)
class StreamSamples:
    errors: SensorErrors          # the simulated unit's (its iron, to build the right calibration from)
    declination_rad: float        # the simulated site's
    t_s: list[float]
    samples: list[ImuSample]      # t_s[k], the block's gyro/accel/mag, counter k, NEW_DATA
    truth_q_wxyz: np.ndarray      # (n, 4) the simulator's attitude

    def until(self, end_s: float):
        """(k, t, sample) up to the first sample at or after `end_s`, which must lie within the samples."""
        if not self.t_s or self.t_s[-1] < end_s:
            raise ValueError(f"the stream was simulated to {self.t_s[-1] if self.t_s else 0.0} s, not {end_s} s")
        for k, t in enumerate(self.t_s):
            yield k, t, self.samples[k]
            if t >= end_s:
                return


def stream_samples(scenario: str, seed: int, seconds: float) -> StreamSamples:
    """`scenario` (the simulator's default rate and errors) with `seed`, read in blocks of BLOCK until a sample at
    or after `seconds`."""
    stream = open_stream(scenario, seed=seed)
    t_s, samples, truth = [], [], []
    while not t_s or t_s[-1] < seconds:
        b = stream.next_block(BLOCK)
        for i in range(len(b.t_s)):
            t = float(b.t_s[i])
            samples.append(make_sample(t, b.gyro_rad_s[i], b.accel_m_s2[i], b.mag_ut[i], counter=len(t_s),
                                       flags=SampleFlags.NEW_DATA))
            t_s.append(t)
        truth.append(b.truth_q_wxyz)
    return StreamSamples(stream.errors, stream.earth_field.declination_rad, t_s, samples, np.concatenate(truth))
