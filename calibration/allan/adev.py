"""Streaming overlapping Allan deviation from a hierarchy of decimated averages, with confidence intervals.

The overlapping Allan variance of rate samples y at cluster size m (τ = m·τ0) is
    σ²(τ) = 1/(2τ²(n−2m+1)) · Σ_i (θ_{i+2m} − 2θ_{i+m} + θ_i)²,   θ_k = τ0·Σ_{j<k} y_j
(IEEE Std 952-1997 Annex C; NIST SP 1065 eq. 14). Holding all n samples costs 8·n bytes per axis (0.57 GB for
24 h at 819.2 SPS), so the record is consumed a chunk at a time:

- level 0 is the samples themselves: cluster sizes 1…13 (4 per octave), every start (fully overlapping);
- level j ≥ 1 is the series of averages of 2^j consecutive samples (built by averaging pairs of level j−1):
  cluster sizes m' = 8, 10, 11, 13 of that series, i.e. τ = m'·2^j·τ0, with cluster starts every 2^j samples.
  A start stride of ≤ m/8 keeps almost all of the overlapping estimator's degrees of freedom (the
  differences of clusters that far apart are nearly uncorrelated for every power-law noise).

Each level keeps only its last 2·m'_max − 1 values and the running sum of squared second differences, so the
memory is a chunk plus a few hundred numbers, whatever the record length.

Confidence: the equivalent degrees of freedom of the overlapping estimator from the simple formulas of
Howe, Allan & Barnes, "Properties of signal sources and measurement methods" (Proc. 35th Freq. Control Symp.,
1981), as tabulated in NIST SP 1065 (Riley, 2008) Table 5, per power-law noise type; the σ interval follows
from σ̂²·edf/σ² ~ χ²(edf) (SP 1065 §5.3.2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .second_differences import add_squared_second_differences

LEVEL0_SIZES = (1, 2, 3, 4, 5, 6, 7)   # below 8: every cluster size of the first octaves, fully overlapping
LEVEL_SIZES = (8, 10, 11, 13)          # ≈ 8·2^(k/4), k = 0..3: 4 points per octave on every level
MAX_TAU_FRACTION = 1.0 / 3.0           # longest τ reported: a third of the record (≥ n/3 overlapping terms)


@dataclass(frozen=True)
class AllanCurve:
    """An overlapping Allan deviation with what its confidence needs.

    taus_s (j,); adev (j, k) per axis; n_terms (j,): overlapping second differences summed; level_n (j,) and
    level_m (j,): the length of the series the point was computed on and its cluster size in that series
    (n/m is the number of independent clusters, T/τ); record_s: the record length T.
    """

    taus_s: np.ndarray
    adev: np.ndarray
    n_terms: np.ndarray
    level_n: np.ndarray
    level_m: np.ndarray
    record_s: float

    @property
    def clusters(self) -> np.ndarray:
        """Independent (non-overlapping) clusters behind each point: T/τ."""
        return self.level_n / self.level_m


class _Level:
    """One level of the hierarchy: a series of 2^j-sample averages, its tail, and the running sums."""

    def __init__(self, decimation: int, sizes: tuple[int, ...], n_axes: int):
        self.decimation = decimation
        self.sizes = np.array(sizes, dtype=np.int64)
        self.tail = np.empty((0, n_axes))
        self.pending = np.empty((0, n_axes))   # a sample waiting for its partner before it is averaged down
        self.n = 0                              # values seen on this level
        self.sum_sq = np.zeros((len(sizes), n_axes))
        self.count = np.zeros(len(sizes), dtype=np.int64)

    def add(self, values: np.ndarray) -> np.ndarray:
        """Take new values of this level; return the pair averages for the next level."""
        if len(values) == 0:
            return values
        buf = np.concatenate([self.tail, values]) if len(self.tail) else values
        theta = np.empty((len(buf) + 1, buf.shape[1]))
        theta[0] = 0.0
        np.cumsum(buf, axis=0, out=theta[1:])
        old = len(self.tail)
        if buf.shape[1] > 1:
            add_squared_second_differences(theta, self.sizes, old, self.sum_sq, self.count)
        else:
            # One column: numpy's einsum sums a contiguous column in blocks (SIMD accumulators), not row by row
            # as the compiled kernel and as it does for several columns: the numpy expressions themselves.
            for i, m in enumerate(self.sizes):
                # windows buf[s : s+2m] that end in the new values: s + 2m − 1 ≥ old
                first = max(0, old - 2 * m + 1)
                last = len(buf) - 2 * m           # inclusive
                if last < first:
                    continue
                d = theta[first + 2 * m:last + 2 * m + 1] - 2.0 * theta[first + m:last + m + 1] + theta[first:last + 1]
                self.sum_sq[i] += np.einsum("ij,ij->j", d, d)
                self.count[i] += last - first + 1
        keep = int(2 * self.sizes.max() - 1)
        self.tail = buf[-keep:].copy()
        self.n += len(values)
        paired = np.concatenate([self.pending, values]) if len(self.pending) else values
        even = len(paired) - len(paired) % 2
        self.pending = paired[even:].copy()
        return 0.5 * (paired[0:even:2] + paired[1:even:2])


class StreamingAllan:
    """Overlapping Allan deviation of a rate signal fed in chunks (`add`), read with `curve()`.

    Memory: O(chunk) plus a few hundred numbers per axis; time: O(n) (≈ 11 cluster sizes on the samples
    themselves, 4 per level on the decimated series, whose total length is n).
    """

    def __init__(self, rate_hz: float, n_axes: int = 3, level0_sizes=LEVEL0_SIZES, decimate: bool = True):
        """level0_sizes, decimate=False: exactly those cluster sizes on the samples, no decimated levels."""
        if not rate_hz > 0:
            raise ValueError(f"sample rate must be positive, got {rate_hz}")
        self.rate_hz = float(rate_hz)
        self.n_axes = n_axes
        self._level0_sizes = tuple(level0_sizes) + (LEVEL_SIZES if decimate else ())
        self._decimate = decimate
        self._levels: list[_Level] = []
        self._offset: np.ndarray | None = None

    @property
    def n_samples(self) -> int:
        return self._levels[0].n if self._levels else 0

    def add(self, x: np.ndarray) -> None:
        """Feed (n,) or (n, k) finite samples, in time order."""
        x = np.asarray(x, dtype=np.float64)
        if x.ndim == 1:
            x = x[:, None]
        if x.shape[1] != self.n_axes:
            raise ValueError(f"expected {self.n_axes} columns, got {x.shape[1]}")
        if not np.all(np.isfinite(x)):
            raise ValueError("Allan variance input contains non-finite samples")
        if len(x) == 0:
            return
        if self._offset is None:
            # The first sample is subtracted from everything: the Allan variance does not see a constant, and
            # the running sums θ stay small (their rounding error would otherwise grow with the bias·n).
            self._offset = x[0].copy()
            self._levels.append(_Level(1, self._level0_sizes, self.n_axes))
        values = x - self._offset
        j = 0
        while len(values) and (j == 0 or self._decimate):
            if j == len(self._levels):
                self._levels.append(_Level(2 ** j, LEVEL_SIZES, self.n_axes))
            values = self._levels[j].add(values)
            j += 1

    def curve(self, max_tau_fraction: float = MAX_TAU_FRACTION) -> AllanCurve:
        """The Allan deviation at every cluster size with enough data (τ ≤ max_tau_fraction·T)."""
        n = self.n_samples
        if n < 8:
            raise ValueError(f"Allan variance needs at least 8 samples, got {n}")
        rows = []
        for level in self._levels:
            for i, m in enumerate(level.sizes):
                tau = m * level.decimation / self.rate_hz
                if level.count[i] == 0 or m * level.decimation > max_tau_fraction * n and m > 1:
                    continue
                avar = level.sum_sq[i] / (2.0 * m * m * level.count[i])   # in (sample units)², averages of m
                rows.append((tau, np.sqrt(avar), level.count[i], level.n, m))
        rows.sort(key=lambda r: r[0])
        taus = np.array([r[0] for r in rows])
        keep = np.concatenate([[True], np.diff(taus) > 0])   # m = 8 on level 0 and m' = ... never repeat; safety
        rows = [r for r, k in zip(rows, keep) if k]
        return AllanCurve(
            taus_s=np.array([r[0] for r in rows]),
            adev=np.array([r[1] for r in rows]),
            n_terms=np.array([r[2] for r in rows], dtype=np.int64),
            level_n=np.array([r[3] for r in rows], dtype=np.float64),
            level_m=np.array([r[4] for r in rows], dtype=np.float64),
            record_s=n / self.rate_hz,
        )


def allan_deviation(x: np.ndarray, rate_hz: float, m: np.ndarray | None = None) -> AllanCurve:
    """Overlapping Allan deviation of an in-memory record `x` ((n,) or (n, k)) at `rate_hz`.

    m None: the streaming hierarchy's octave-spaced cluster sizes. m given: exactly those cluster sizes,
    fully overlapping (every start), on the samples themselves.
    """
    x = np.asarray(x, dtype=np.float64)
    cols = 1 if x.ndim == 1 else x.shape[1]
    if m is None:
        acc = StreamingAllan(rate_hz, cols)
        acc.add(x)
        return acc.curve()
    acc = StreamingAllan(rate_hz, cols, level0_sizes=tuple(int(v) for v in np.atleast_1d(m)), decimate=False)
    acc.add(x)
    return acc.curve(max_tau_fraction=0.5)


def edf_overlapping(alpha: int, n_points: float, m: float) -> float:
    """Equivalent degrees of freedom of the overlapping Allan variance (NIST SP 1065 Table 5, after Howe,
    Allan & Barnes 1981) for power-law FM noise S_y(f) ∝ f^alpha: 2 white PM (here: angle quantization),
    1 flicker PM, 0 white FM (white rate noise), −1 flicker FM (bias instability), −2 random-walk FM (rate
    random walk). n_points: phase points (samples + 1); m: cluster size in samples."""
    n, m = float(n_points), float(m)
    if alpha == 2:
        edf = (n + 1.0) * (n - 2.0 * m) / (2.0 * (n - m))
    elif alpha == 1:
        edf = math.exp(math.sqrt(max(math.log((n - 1.0) / (2.0 * m)), 0.0) * math.log((2.0 * m + 1.0) * (n - 1.0) / 4.0)))
    elif alpha == 0:
        edf = (3.0 * (n - 1.0) / (2.0 * m) - 2.0 * (n - 2.0) / n) * 4.0 * m * m / (4.0 * m * m + 5.0)
    elif alpha == -1:
        edf = 2.0 * (n - 2.0) / (2.3 * n - 4.9) if m == 1 else 5.0 * n * n / (4.0 * m * (n + 3.0 * m))
    elif alpha == -2:
        edf = (n - 2.0) / m * ((n - 1.0) ** 2 - 3.0 * m * (n - 1.0) + 4.0 * m * m) / (n - 3.0) ** 2
    else:
        raise ValueError(f"no EDF formula for alpha = {alpha}")
    return max(edf, 1.0)


EDF_ALPHAS = (-2, -1, 0, 1, 2)   # the noise types edf_overlapping has a formula for


def edf_by_alpha(level_n: np.ndarray, level_m: np.ndarray) -> np.ndarray:
    """edf_overlapping of every point (series length n, i.e. n + 1 phase points; cluster size m) for every
    noise type: row α + 2 for α = −2…2, so a point's edf for a given α is a look-up."""
    return np.array([[edf_overlapping(alpha, n + 1.0, m) for n, m in zip(level_n, level_m)] for alpha in EDF_ALPHAS])


def alpha_from_slope(avar_slope: float) -> int:
    """Power-law exponent α of S_y ∝ f^α from the local log-log slope μ of σ²(τ) ∝ τ^μ: μ = −α − 1 for
    −2 ≤ α ≤ 1 (white PM, α = 2, also has μ = −2: the quantization noise here)."""
    return int(min(2, max(-2, round(-avar_slope - 1.0))))


ONE_SIGMA = math.erf(1.0 / math.sqrt(2.0))   # 0.6827: the two-sided 1σ probability


def confidence_interval(adev: np.ndarray, edf: np.ndarray, level: float = ONE_SIGMA) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) bounds on σ from σ̂²·edf/σ² ~ χ²(edf), two-sided at `level` (SP 1065 §5.3.2)."""
    from scipy.stats import chi2

    tail = 0.5 * (1.0 - level)
    edf = np.asarray(edf, dtype=np.float64)
    lower = adev * np.sqrt(edf / chi2.ppf(1.0 - tail, edf))
    upper = adev * np.sqrt(edf / chi2.ppf(tail, edf))
    return lower, upper
