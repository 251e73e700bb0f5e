"""Samples of random readings at the chip's rate, with every field a log writes set (flags cycling, a counter,
temperature, supply): for the log tests, which compare what reads back with what went in, byte for byte."""

from __future__ import annotations

import numpy as np

from ahrsd.core.sample import SampleFlags, make_sample


def random_samples(n, t0=100.0, rate_hz=819.2, seed=0):
    rng = np.random.default_rng(seed)
    return [make_sample(t0 + k / rate_hz, rng.normal(size=3), rng.normal(size=3) + [0, 0, -9.8],
                        rng.normal(size=3) * 20, temp_c=25.0 + k * 1e-4, supply_v=5.0, flags=SampleFlags(k % 4),
                        counter=k) for k in range(n)]
