"""The lever-arm check's terms at a fix as plain Python, the reference the compiled innovation
(estimator/lever_arm_kernel.py) is checked against and the builder of the tests' LeverArmFit inputs: the rows of
ins's history near the fix (a mask over every kept row), their mean body rate (the sums numpy's
`sum(axis=0) / len` makes) and C [ω×]. This was the filter's own Python until session 39 compiled it; the digests
of tools/estimate_digest.py were made with it."""

from __future__ import annotations

import numpy as np

from ahrsd.estimator.lever_arm_fit import RATE_MEAN_S
from ahrsd.estimator.rotations import skew


def rows_near(t_rows_s: np.ndarray, newest: int, count: int, t_s: float, half_span_s: float) -> np.ndarray:
    """Ring indices, newest first, of the kept rows (the `count` rows up to ring index `newest` of the ring's row
    times `t_rows_s`) with |t − t_s| ≤ half_span_s: a mask over all of them."""
    kept = (newest - np.arange(count)) % len(t_rows_s)
    return kept[np.abs(t_rows_s[kept] - t_s) <= half_span_s]


def mean_rate(t_rows_s: np.ndarray, rate_rows_rad_s: np.ndarray, t_s: float, rate_at_rad_s: np.ndarray) -> np.ndarray:
    """The body rate for the arm's term at a fix of time t_s: the mean of the rates (rows of body rate, rad/s, at
    times t_rows_s) within RATE_MEAN_S about t_s, or `rate_at_rad_s` when no row is within it."""
    half_s = 0.5 * RATE_MEAN_S
    n = 0
    sx = sy = sz = 0.0
    # in Python floats: the mean as numpy's `sum(axis=0) / len` computes it, from +0.0 adding the rows in their
    # order (along a (k, 3) array's rows numpy adds row after row, no pairwise summation), then divided by their
    # count: the same value to the bit (test_lever_arm_fit.py checks it against numpy's)
    for t, (x, y, z) in zip(np.asarray(t_rows_s).tolist(), np.asarray(rate_rows_rad_s).tolist()):
        if abs(t - t_s) <= half_s:
            sx += x
            sy += y
            sz += z
            n += 1
    return np.array([sx / n, sy / n, sz / n]) if n else np.asarray(rate_at_rad_s, dtype=float)


def rate_cross_ned(c_bn: np.ndarray, rate_b_rad_s: np.ndarray) -> np.ndarray:
    """C [ω×]: the NED velocity of an antenna offset δr (body) per metre of δr, as a 3 × 3 matrix."""
    return c_bn @ skew(rate_b_rad_s)
