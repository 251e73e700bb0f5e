"""Synthetic noise with known IEEE Std 952 terms, for the Allan tests, bench and tools/allan_digest.py (independent
of the analysis).

Each generator returns rate samples (n,) at `rate_hz` (white, rate_random_walk and gauss_markov also take a shape
(n, axes): samples along the first axis) whose Allan variance is, per term:
white N: N²/τ; rate random walk K: K²τ/3; flicker B: (0.664·B)² (one-sided PSD B²/(π f)); Gauss–Markov σ, Tc;
quantization Q: 3Q²/τ² (white angle noise of variance Q², differenced).
"""

from __future__ import annotations

import math

import numpy as np


def white(n: int, rate_hz: float, density: float, rng) -> np.ndarray:
    """White rate noise of density N (u/√Hz): per-sample σ = N·√rate."""
    return rng.standard_normal(n) * density * math.sqrt(rate_hz)


def rate_random_walk(n: int, rate_hz: float, k: float, rng) -> np.ndarray:
    """Random walk of the rate: increments of σ = K·√dt per sample."""
    return np.cumsum(rng.standard_normal(n), axis=0) * k / math.sqrt(rate_hz)


def flicker(n: int, rate_hz: float, b: float, rng) -> np.ndarray:
    """1/f rate noise by Kasdin & Walter's fractional-difference filter (Proc. IEEE Freq. Control Symp. 1992;
    Kasdin, Proc. IEEE 83(5), 1995, eq. 115): h_0 = 1, h_k = h_{k−1}·(α/2 + k − 1)/k with α = 1, driven by
    white noise of variance Q_d. One-sided PSD 2·Q_d·dt/|2 sin(π f dt)| → Q_d/(π f) at low f; IEEE Std 952's
    flicker S(f) = B²/(π f) one-sided gives Q_d = B², and σ_A = √(2 ln2/π)·B."""
    from scipy.signal import fftconvolve

    return fftconvolve(rng.standard_normal(n) * b, kasdin_taps(n))[:n]


def kasdin_taps(count: int) -> np.ndarray:
    """The first `count` taps h_k of Kasdin & Walter's 1/f filter (α = 1): h_0 = 1, h_k = h_{k−1}·(α/2 + k − 1)/k."""
    k = np.arange(1, count)
    return np.concatenate([[1.0], np.cumprod((0.5 + k - 1.0) / k)])


def gauss_markov(n, rate_hz: float, sigma: float, corr_time_s: float, rng, from_rest: bool = False) -> np.ndarray:
    """First-order Gauss–Markov (exponentially correlated) bias of stationary σ and correlation time Tc, started
    from a draw of its stationary distribution (from_rest: from 0, no draw)."""
    from scipy.signal import lfilter

    phi = math.exp(-1.0 / (rate_hz * corr_time_s))
    drive = rng.standard_normal(n) * sigma * math.sqrt(1.0 - phi * phi)
    if from_rest:
        return lfilter([1.0], [1.0, -phi], drive, axis=0)
    x0 = rng.standard_normal() * sigma
    out, _ = lfilter([1.0], [1.0, -phi], drive, zi=[phi * x0])
    return out


def quantization(n: int, rate_hz: float, q: float, rng) -> np.ndarray:
    """Quantization noise as IEEE Std 952 models it: white angle noise of σ = Q (uniform, step √12·Q),
    differenced into rate: (e_k − e_{k−1})·rate."""
    step = math.sqrt(12.0) * q
    e = rng.uniform(-step / 2, step / 2, n + 1)
    return np.diff(e) * rate_hz
