"""Block averaging: samples decimated to a fit rate by averaging consecutive blocks of 1/rate seconds."""

from __future__ import annotations

import numpy as np


def block_average(t_s: np.ndarray, rate_hz: float, *columns):
    """Average consecutive samples in blocks of 1/rate_hz seconds. Returns (t_block, [averaged columns]) and
    the block index of every input sample. Columns may be None."""
    t = np.asarray(t_s, dtype=np.float64)
    if t.size == 0:
        return t, [c for c in columns], np.zeros(0, dtype=int)
    if rate_hz is None or rate_hz <= 0:
        return t, list(columns), np.arange(t.size)
    idx = np.floor((t - t[0]) * rate_hz).astype(np.int64)
    _, inv, counts = np.unique(idx, return_inverse=True, return_counts=True)
    nb = counts.size

    def avg(x):
        if x is None:
            return None
        x = np.asarray(x, dtype=np.float64)
        out = np.zeros((nb,) + x.shape[1:])
        np.add.at(out, inv, x)
        return out / counts.reshape((-1,) + (1,) * (x.ndim - 1))

    return avg(t), [avg(c) for c in columns], inv
