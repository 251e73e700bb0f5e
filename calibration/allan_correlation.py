"""How many samples apart a sensor's samples stop being correlated, and so the shortest τ the Allan fit may use.

A sensor's digital filter (the ADIS16405's SENS_AVG Bartlett window, an anti-alias filter, a decimator) makes
neighbouring samples correlated: the Allan deviation of its white noise then falls below N/√τ for τ within a few
filter lengths and bends like a short Gauss–Markov bump, and a fit over those τ reads the white noise as that bump
(IEEE Std 952-1997 C.1 assumes the samples are independent at the shortest τ). The fit is therefore given only the
τ of at least FIT_LENGTHS correlation lengths, where the filter's share of the white-noise Allan variance is below
about 1/FIT_LENGTHS of it; uncorrelated samples (length 1) keep every τ.

The length is read from the data, not from a chip model: the autocorrelation of the first CORR_SAMPLES samples of
each axis (mean removed; on a static record white noise dominates the sample-to-sample variance). The length is
the first lag where it falls below CORR_THRESHOLD, if that is within MAX_LAG/4 and the correlation then vanishes:
every lag from twice the length to MAX_LAG below TAIL_THRESHOLD (about 7σ of the estimate's noise for CORR_SAMPLES
samples). A correlation that lingers is a slow process (a Gauss–Markov bias, a random walk) that the term fit
models itself: those samples keep every τ.
"""

from __future__ import annotations

import numpy as np

CORR_SAMPLES = 16384
MAX_LAG = 64
CORR_THRESHOLD = 0.1
TAIL_THRESHOLD = 0.06
FIT_LENGTHS = 8


class SampleCorrelation:
    """`add(rows)` until it has CORR_SAMPLES rows (later rows are ignored), then `lengths()`."""

    def __init__(self, n_axes: int = 3):
        self._rows: list[np.ndarray] = []
        self._n = 0
        self._n_axes = n_axes

    def add(self, data: np.ndarray) -> None:
        if self._n >= CORR_SAMPLES:
            return
        take = np.asarray(data, dtype=np.float64)[: CORR_SAMPLES - self._n]
        self._rows.append(take)
        self._n += len(take)

    def lengths(self) -> np.ndarray:
        """Per axis: the filter's correlation length in samples (see the module doc); 1 for independent samples,
        for a slow process and with too few samples to tell."""
        out = np.ones(self._n_axes, dtype=int)
        if self._n < 4 * MAX_LAG:
            return out
        x = np.concatenate(self._rows)
        x = x - x.mean(axis=0)
        n = len(x)
        lags = np.arange(1, MAX_LAG + 1)
        for axis in range(self._n_axes):
            col = x[:, axis]
            var = float(np.dot(col, col)) / n
            if not var > 0:
                continue
            rho = np.array([np.dot(col[:-lag], col[lag:]) / (n - lag) for lag in lags]) / var
            below = np.flatnonzero(rho < CORR_THRESHOLD)
            if not len(below) or below[0] == 0 or below[0] > MAX_LAG // 4:
                continue                          # independent, or correlated too long for a filter
            length = int(below[0]) + 1
            if np.all(np.abs(rho[2 * length - 1:]) < TAIL_THRESHOLD):   # and then it vanishes: a filter's
                out[axis] = length
        return out


def shortest_fit_tau_s(length_samples: int, rate_hz: float) -> float:
    """The shortest τ the term fit uses for samples correlated over `length_samples` (0: every τ)."""
    return 0.0 if length_samples <= 1 else FIT_LENGTHS * length_samples / rate_hz
