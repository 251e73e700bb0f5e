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
every lag from twice the length to MAX_LAG below TAIL_THRESHOLD (many times the estimate's noise, 1/√CORR_SAMPLES;
CORR_SAMPLES is large for D below, whose error moves N directly). A correlation that lingers is a slow process (a Gauss–Markov bias, a random walk) that the term fit
models itself: those samples keep every τ.

A short record cannot always tell the two apart. Beyond a filter's span the estimated autocorrelation scatters
with variance (1 + 2·Σρ(j)²)/n over the lags j of the span (Bartlett's formula, Box & Jenkins, Time Series
Analysis, §6.2.2), which for a long filter is many times 1/n; the tail then only says "slow process" when
TAIL_THRESHOLD is TELL_SIGMAS of that scatter. A record with correlated neighbours (lag-1 correlation above
CORR_THRESHOLD) whose tail is above the threshold but within that scatter, or that has fewer than 4·MAX_LAG
samples, has a correlation length nobody can tell: `samples_to_tell` says how many samples would, and the Allan
fit reads no term from it (a fit over every τ would read the filter as a Gauss–Markov bump).

Beyond its span the filter still lowers the white noise's Allan variance, by a share that falls as 1/τ: a filter
with unit gain at zero frequency turns the phase's covariance G(h) = −|h|/2 (a Brownian motion) into its average
over the lag distribution a(s) of the filter's autocorrelation, which is G again for |h| beyond the span and
−E|s|/2 at h = 0, so the second difference loses 3·E|s| of its variance and
    σ²(τ) = N²·(1/τ − D/τ²),   D = (3/2)·E|s| = (3/2)·Σ|s|·ρ(s) / Σρ(s)   (s over the filter's span, both signs).
The term fit takes white noise in that form (`deficits_s`), so the few percent the filter takes off at the
shortest fitted τ do not bias N.
"""

from __future__ import annotations

import numpy as np

CORR_SAMPLES = 1 << 18
MAX_LAG = 64
CORR_THRESHOLD = 0.1
TAIL_THRESHOLD = 0.06
FIT_LENGTHS = 8
TELL_SIGMAS = 4.0     # a filter's tail passes TAIL_THRESHOLD over ~60 lags but in 1 record of ~300 (normal tails)


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
        for a slow process and where the record is too short to tell (samples_to_tell)."""
        return self._filter()[0]

    def deficits_s(self, rate_hz: float) -> np.ndarray:
        """Per axis: D (s) of the filter's share of the white noise's Allan variance, N²·D/τ² (module doc);
        0 where lengths() finds no filter."""
        return self._filter()[1] / rate_hz

    def samples_to_tell(self) -> np.ndarray:
        """Per axis: 0 when the samples tell their correlation (a filter's length, independent samples or a slow
        process), else about how many samples would tell it (module doc)."""
        return self._filter()[2]

    def _filter(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(lengths, deficits in samples, samples needed to tell) per axis."""
        lengths, deficits = np.ones(self._n_axes, dtype=int), np.zeros(self._n_axes)
        needed = np.zeros(self._n_axes, dtype=int)
        if self._n < 8:
            return lengths, deficits, needed      # nothing to read; the Allan fit has too few cluster sizes anyway
        x = np.concatenate(self._rows)
        x = x - x.mean(axis=0)
        n = len(x)
        lags = np.arange(1, min(MAX_LAG, n // 4) + 1)    # every lag to MAX_LAG once there are 4·MAX_LAG samples
        for axis in range(self._n_axes):
            col = np.ascontiguousarray(x[:, axis])    # contiguous: dot products over a strided column do not vectorise
            var = float(np.dot(col, col)) / n
            if not var > 0:
                continue
            rho = np.array([np.dot(col[:-lag], col[lag:]) / (n - lag) for lag in lags]) / var
            below = np.flatnonzero(rho < CORR_THRESHOLD)
            if rho[0] < CORR_THRESHOLD:
                continue                          # independent neighbours
            if not len(below) or below[0] > MAX_LAG // 4:
                continue                          # correlated too long for a filter: a slow process
            length = int(below[0]) + 1
            # The filter's lags (to twice its length) set the scatter of the tail (Bartlett's formula), and with
            # it the record that tells a filter from a slow process.
            tell = max(4 * MAX_LAG, int(np.ceil((TELL_SIGMAS / TAIL_THRESHOLD) ** 2
                                                * (1.0 + 2.0 * float(np.sum(rho[:2 * length] ** 2))))))
            if n >= 4 * MAX_LAG and np.all(np.abs(rho[2 * length - 1:]) < TAIL_THRESHOLD):   # then it vanishes: a filter's
                lengths[axis] = length
                # D sums the filter's span: the lags up to where the correlation is lost in the estimate's noise
                # (2/√n) from the length on, at most 2·length (each noisy lag adds its lag times its noise)
                lost = np.flatnonzero(rho[length - 1:2 * length] < 2.0 / np.sqrt(n))
                span = rho[:length - 1 + int(lost[0])] if len(lost) else rho[:2 * length]
                deficits[axis] = 1.5 * 2.0 * float(np.dot(lags[:len(span)], span)) / (1.0 + 2.0 * float(np.sum(span)))
            elif n < tell:
                needed[axis] = tell               # the tail is within the estimate's scatter: filter or slow process?
        return lengths, deficits, needed


def shortest_fit_tau_s(length_samples: int, rate_hz: float) -> float:
    """The shortest τ the term fit uses for samples correlated over `length_samples` (0: every τ)."""
    return 0.0 if length_samples <= 1 else FIT_LENGTHS * length_samples / rate_hz
