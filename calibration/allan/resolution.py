"""Whether a sensor's output resolution (its ADC's LSB) is fine enough for its noise to be read at all.

A sensor that averages many samples before rounding them (the ADIS16405 with a long SENS_AVG window: at N = 7 the
accelerometer's filtered noise is 0.21 LSB, the magnetometer's 0.18) outputs a handful of values. Its rounding is
then no white noise added to the signal (that needs the signal to move over several LSB between samples, Widrow &
Kollár, Quantization Noise, 2008, ch. 4–5) but a staircase of the slowly moving filtered signal, and the Allan
deviation of the output is the staircase's: the white noise read against the configured density drifts high
as the output's σ per sample (rounding included) falls below an LSB, and other terms take its place (the figures
per filter setting, and the threshold held out: docs/calibration.md "An output too coarse for its noise"). Below
MIN_NOISE_LSB the analysis reads no term and says to lower the filter setting instead. The σ is the samples' own
(a slow process adds to it, so an axis is never refused for it).
"""

from __future__ import annotations

import math

import numpy as np

MIN_NOISE_LSB = 0.6
GRID_TOLERANCE = 1e-3     # steps within this many LSB of a whole number of LSB lie on the grid (CSV digits)


def output_lsb(x: np.ndarray) -> float | None:
    """The output's step if (almost) every sample-to-sample step is a whole number of the smallest one, else None."""
    steps = np.abs(np.diff(np.asarray(x, dtype=np.float64)))
    moved = steps[steps > 0]
    if len(moved) < 2:
        return None
    lsb = float(np.min(moved))
    on_grid = np.abs(moved / lsb - np.round(moved / lsb)) < GRID_TOLERANCE
    return lsb if float(np.mean(on_grid)) > 0.99 else None


def noise_in_lsb(variance: float, lsb: float | None) -> float:
    """σ per sample in LSB (the output's, its rounding included); inf without a grid."""
    if lsb is None or not lsb > 0:
        return math.inf
    return math.sqrt(max(variance, 0.0)) / lsb
