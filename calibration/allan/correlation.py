"""How many samples apart a sensor's samples stop being correlated, and so the shortest τ the Allan fit may use.

A sensor's digital filter (the ADIS16405's SENS_AVG Bartlett window, two 2^N-tap averages for N = 0…7, an
anti-alias filter, a decimator) makes neighbouring samples correlated: the Allan deviation of its white noise
then falls below N/√τ for τ within a few filter lengths and bends like a short Gauss–Markov bump, and a fit over
those τ reads the white noise as that bump (IEEE Std 952-1997 C.1 assumes the samples are independent at the
shortest τ). The fit is therefore given only the τ of at least FIT_LENGTHS correlation lengths: beyond the filter's
span (a Bartlett window's correlation length is 0.64 (N = 7) to 1 (N = 1) of its span), where filtered white noise
is N²·(1/τ − D/τ²) exactly (below), which the fit models, so the white noise is read over as many octaves as the
filter leaves; uncorrelated samples (length 1) keep every τ.

The filter is read from the data, not from a chip model, and from the steps between samples (first differences) of
the first CORR_SAMPLES samples of each axis, not from the samples: a slow process (a Gauss–Markov bias, a random
walk, a drift) has a covariance that is nearly straight over a filter's span and so almost no second difference,
while the steps' autocovariance is minus the second difference of the samples' (C_Δ(k) = 2C(k) − C(k−1) − C(k+1)).
In the steps a filter's correlation ends at its span, whatever slow process lies beside it: the span is the
shortest lag beyond which the steps' autocorrelation is zero within TELL_SIGMAS of its scatter over the next 3·span
+ 16 lags (Bartlett's formula for a moving average of that order: √((1 + 2·Σρ(j)²)/n), Box & Jenkins, Time Series
Analysis, §6.2.2). Beyond the span, the samples' autocovariance is the slow process's alone, nearly straight over a
few spans: less the straight line fitted to it there, it is the filtered white noise's own; its correlation length
is the last lag where its autocorrelation is still CORR_THRESHOLD or more. A record of fewer than TELL_SPANS spans
reads the length and D too loosely (synthetic Bartlett windows of 7 to 255 taps, 30 records each: at 400 spans
0.85…1.19 and 0.75…1.15 of the window's, at 100 spans D down to 0.09 of it): it reads no term and `samples_to_tell`
says how many samples would (twice that many: a short record reads the span short). Independent samples have steps
correlated at lag 1 only (span 1), whatever slow process lies beside them. Steps correlated beyond a quarter of the
lags the record has (at most MAX_LAG) are no filter: every τ is kept.

An ADC's rounding is white noise added after the filter (LSB²/12 per sample). Beside a long window it dominates the
sample-to-sample steps (the ADIS16405's gyro at N = 7: 500 to 1), whose lag-1 autocorrelation then reads −0.5 as for
independent samples. When the samples lie on a grid whose rounding is half the steps' variance or more, the steps
x(t) − x(t − d) over d = 2, 4, … STEP_LAGS[-1] are read instead: their autocovariance 2C(k) − C(k − d) − C(k + d)
holds the window's correlation at full strength from lag d to d + span, the rounding's only at lags 0 and d, and a
slow process's only as far as it bends over d. The first d that shows a span of at least d beyond itself gives it.

Beyond its span the filter still lowers the white noise's Allan variance, by a share that falls as 1/τ: a filter
with unit gain at zero frequency turns the phase's covariance G(h) = −|h|/2 (a Brownian motion) into its average
over the lag distribution a(s) of the filter's autocorrelation, which is G again for |h| beyond the span and
−E|s|/2 at h = 0, so the second difference loses 3·E|s| of its variance and
    σ²(τ) = N²·(1/τ − D/τ²),   D = (3/2)·E|s| = (3/2)·Σ|s|·ρ(s) / Σρ(s)   (s over the filter's span, both signs).
The term fit takes white noise in that form (`deficits_s`), so the few percent the filter takes off at the
shortest fitted τ do not bias N. D is read from a finite record, so near the span its error weighs as N²·δD/τ²:
`deficit_sds_s` is δD, from the scatter of D over DEFICIT_BLOCKS blocks of the samples it was read from (the
span of the whole read, each block's D by the same formula; δD = their standard deviation / √DEFICIT_BLOCKS),
which the term fit carries as the uncertainty of the white term's shape (terms).
"""

from __future__ import annotations

import numpy as np

from .resolution import noise_in_lsb, output_lsb

CORR_SAMPLES = 1 << 18
MAX_LAG = 4096        # the chip's longest window (N = 7: 255 taps) seen through steps of 256 needs lags to 4·512 + 16
STEP_LAGS = tuple(1 << j for j in range(9))   # 1 … 256: steps long enough to see a 255-tap window beside 14-bit LSBs
CORR_THRESHOLD = 0.1
FIT_LENGTHS = 2
TELL_SIGMAS = 4.0     # a tail lag beyond 4σ by chance: ~6e-5 per lag (normal tails)
TELL_SPANS = 400      # spans a record needs to read the window's length and D (module doc)
DEFICIT_BLOCKS = 8    # blocks over which D's scatter gives its uncertainty (module doc)


class SampleCorrelation:
    """`add(rows)` until it has CORR_SAMPLES rows (later rows are ignored), then `lengths()`."""

    def __init__(self, n_axes: int = 3):
        self._rows: list[np.ndarray] = []
        self._n = 0
        self._n_axes = n_axes
        self._read: tuple[int, tuple] | None = None      # (samples it was read from, _filter's result)
        self._deficit_sds: np.ndarray | None = None      # δD in samples per axis, read with the filter

    def add(self, data: np.ndarray) -> None:
        if self._n >= CORR_SAMPLES:
            return
        take = np.asarray(data, dtype=np.float64)[: CORR_SAMPLES - self._n]
        self._rows.append(take)
        self._n += len(take)

    def lengths(self) -> np.ndarray:
        """Per axis: the filter's correlation length in samples (see the module doc); 1 for independent samples,
        for steps correlated beyond any filter and where the record is too short to tell (samples_to_tell)."""
        return self._filter()[0]

    def deficits_s(self, rate_hz: float) -> np.ndarray:
        """Per axis: D (s) of the filter's share of the white noise's Allan variance, N²·D/τ² (module doc);
        0 where lengths() finds no filter."""
        return self._filter()[1] / rate_hz

    def deficit_sds_s(self, rate_hz: float) -> np.ndarray:
        """Per axis: the 1σ of deficits_s (s), from D's scatter over blocks of the samples (module doc); 0 where
        lengths() finds no filter."""
        self._filter()
        return self._deficit_sds / rate_hz

    def samples_to_tell(self) -> np.ndarray:
        """Per axis: 0 when the samples tell their correlation (a filter's length, independent samples, or steps
        correlated beyond any filter), else about how many samples would tell it (module doc)."""
        return self._filter()[2]

    def noise_lsb(self) -> np.ndarray:
        """Per axis: the output's σ per sample in its LSB (resolution); inf for an output not on a grid."""
        return self._filter()[3]

    def _filter(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(lengths, deficits in samples, samples needed to tell, noise in LSB) per axis (module doc), read once
        per length."""
        if self._read is None or self._read[0] != self._n:
            self._read = (self._n, self._read_filter())
        return self._read[1]

    def _read_filter(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        lengths, deficits = np.ones(self._n_axes, dtype=int), np.zeros(self._n_axes)
        needed = np.zeros(self._n_axes, dtype=int)
        noise_lsb = np.full(self._n_axes, np.inf)
        self._deficit_sds = np.zeros(self._n_axes)
        if self._n < 8:
            return lengths, deficits, needed, noise_lsb   # nothing to read; the Allan fit has too few cluster sizes
        x = np.concatenate(self._rows)
        n = len(x)
        max_lag = min(MAX_LAG, n // 4)
        for axis in range(self._n_axes):
            col = np.ascontiguousarray(x[:, axis])
            noise_lsb[axis] = noise_in_lsb(float(np.var(col)), output_lsb(col))
            span = _filter_span(col, max_lag)
            if span is None:
                continue                          # independent samples, or correlated beyond any filter
            if n < TELL_SPANS * span:
                needed[axis] = 2 * TELL_SPANS * span   # a short record reads the span short
                continue
            white = _white_autocovariance(_autocovariance(col, max_lag), span)
            if not white[0] > 0 or white[1] < CORR_THRESHOLD * white[0]:
                continue                          # independent neighbours
            lengths[axis] = int(np.flatnonzero(white >= CORR_THRESHOLD * white[0])[-1]) + 1
            deficits[axis] = _deficit(white)
            self._deficit_sds[axis] = _deficit_sd(col, span)
        return lengths, deficits, needed, noise_lsb


def _deficit(white: np.ndarray) -> float:
    """D in samples from the filtered white noise's autocovariance at lags 0…span (module doc)."""
    lags = np.arange(len(white))
    return 1.5 * 2.0 * float(np.dot(lags, white)) / (white[0] + 2.0 * float(np.sum(white[1:])))


def _deficit_sd(x: np.ndarray, span: int) -> float:
    """The 1σ of D read from all of x: the standard deviation of D over DEFICIT_BLOCKS blocks of x (each read with
    the whole record's span) over √DEFICIT_BLOCKS (module doc)."""
    blocks = np.array_split(x, DEFICIT_BLOCKS)
    max_lag = int(tail_lags(span, MAX_LAG)[-1])
    if len(blocks[-1]) < 4 * max_lag:
        return 0.0
    each = [_deficit(_white_autocovariance(_autocovariance(b, max_lag), span)) for b in blocks]
    return float(np.std(each, ddof=1)) / np.sqrt(DEFICIT_BLOCKS)


def _filter_span(x: np.ndarray, max_lag: int) -> int | None:
    """The first lag where the filter's correlation of x has ended, read from its steps (module doc); None when
    no step shows a filter at least as long as the step."""
    end = _step_span(x, 1, max_lag)
    if end is None or end >= 2:
        return end
    if not _rounding_dominates_the_steps(x):
        return None                               # independent samples (beside any slow process)
    for d in STEP_LAGS[1:]:
        if 4 * (2 * d) + 16 > max_lag:
            return None                           # too few lags for this step
        end = _step_span(x, d, max_lag)
        if end is None:
            return None                           # correlated beyond any filter: a slow process shows through
        if end - d >= d:
            return end - d + 1
    return None


def _rounding_dominates_the_steps(x: np.ndarray) -> bool:
    """Whether x is on a grid (an ADC's LSB) whose rounding, white noise of LSB²/12 added after the filter, is
    at least half the variance of the sample-to-sample steps (their lag-1 autocorrelation then reads −0.5 as
    for independent samples, whatever the filter)."""
    lsb = output_lsb(x)
    return lsb is not None and 2.0 * lsb * lsb / 12.0 >= 0.5 * float(np.var(np.diff(x)))


def _step_span(x: np.ndarray, d: int, max_lag: int) -> int | None:
    """The span of the autocorrelation of the steps x(t) − x(t − d), searched from lag d (_span)."""
    steps = x[d:] - x[:-d]
    cov = _autocovariance(steps, max_lag)
    if not cov[0] > 0:
        return None
    return _span(cov / cov[0], len(steps), first=d)


def _autocovariance(x: np.ndarray, max_lag: int) -> np.ndarray:
    """Autocovariance of x (mean removed) at lags 0…max_lag, through the FFT (zero-padded: no wrap-around; a
    fast length just above n + max_lag, not the next power of two, keeps the buffers near the samples' size)."""
    from scipy import fft

    size = fft.next_fast_len(len(x) + max_lag + 1, real=True)
    f = np.fft.rfft(x - x.mean(), size)
    power = f.real**2 + f.imag**2
    del f
    return np.fft.irfft(power, size)[:max_lag + 1] / len(x)


def _span(rho: np.ndarray, n: int, first: int = 1) -> int | None:
    """The shortest lag k ≥ first beyond which the autocorrelation rho of the steps is zero within TELL_SIGMAS of its
    scatter, √((1 + 2·Σ_{j≤k} ρ(j)²)/n) (Bartlett's formula for a moving average of order k), over the next
    3k + 16 lags (tail_lags); None when no k up to a quarter of the lags has such a tail."""
    max_lag = len(rho) - 1
    scatter = np.sqrt((2.0 * np.cumsum(rho**2) - 1.0) / n)
    for k in range(first, max_lag // 4 + 1):
        if np.all(np.abs(rho[tail_lags(k, max_lag)]) < TELL_SIGMAS * scatter[k]):
            return k
    return None


def tail_lags(span: int, max_lag: int) -> np.ndarray:
    """The lags beyond a span of `span` lags where a filter's correlation is zero: span + 1 … 4·span + 16."""
    return np.arange(span + 1, min(max_lag, 4 * span + 16) + 1)


def _white_autocovariance(cov: np.ndarray, span: int) -> np.ndarray:
    """The filtered white noise's autocovariance at lags 0…span: the samples' autocovariance less the straight
    line fitted to it over the tail beyond the span (a slow process's covariance, nearly straight over the
    span, which the steps do not show; the filter's is zero there)."""
    tail = tail_lags(span, len(cov) - 1)
    slope, offset = np.polyfit(tail, cov[tail], 1)
    lags = np.arange(span + 1)
    return cov[:span + 1] - (offset + slope * lags)


def shortest_fit_tau_s(length_samples: int, rate_hz: float) -> float:
    """The shortest τ the term fit uses for samples correlated over `length_samples` (0: every τ)."""
    return 0.0 if length_samples <= 1 else FIT_LENGTHS * length_samples / rate_hz
