"""estimator/history_rows.py: reading ins's history ring at a fix's time by binary search gives what the kernel's walk
back from the newest row gives (`ins_core._history_at`)."""

from __future__ import annotations

import numpy as np
import pytest

from ahrsd.estimator import ins_core as core
from ahrsd.estimator.history_rows import bracket

H = core.H_LEN


def _ring(rng, count: int, newest: int, rate_hz: float, t0_s: float = 1000.0):
    """A history ring with `count` kept rows up to `newest`, at irregular steps about 1/rate_hz (strictly increasing,
    as the kernel writes them); the rows not kept hold stale times (ahead of the kept ones: an older run's)."""
    hist = np.zeros(H, core.INS_HISTORY_DTYPE)
    hist["t_s"] = t0_s + 1e6        # stale rows: later than any kept one, which a search must not read
    dt = rng.uniform(0.2, 1.8, count) / rate_hz
    times = t0_s + np.cumsum(dt)
    hist["t_s"][(newest - count + 1 + np.arange(count)) % H] = times
    x = np.zeros(1, core.INS_STATE_DTYPE)[0]
    x["hist_newest"] = newest
    x["hist_count"] = count
    return x, hist, times


CASES = [(1, 0), (2, 5), (40, 10), (H, 3), (H, H - 1), (H, 500), (700, 200)]


@pytest.mark.parametrize("count,newest", CASES)
def test_bracket_is_the_kernels(count, newest):
    rng = np.random.default_rng(count * 7 + newest)
    x, hist, times = _ring(rng, count, newest, 819.2)
    some = np.unique(np.concatenate([rng.integers(0, count, 30), [0, count - 1]]))
    queries = np.concatenate([times[some],                             # exactly on a row
                              times[some[:-1]] + 0.37 * (times[some[:-1] + 1] - times[some[:-1]]),   # between rows
                              [times[0] - 1e-3, times[-1] + 1e-3, times[-1], times[0], np.nan],
                              rng.uniform(times[0] - 0.1, times[-1] + 0.1, 50)])
    for t in queries:
        got = bracket(hist["t_s"], newest, count, float(t))
        want = core._history_at(x, hist, float(t))
        assert got[:2] == tuple(want[:2]), t
        assert got[2] == want[2], t          # the same weight, bit for bit


def test_bracket_without_rows():
    hist = np.zeros(H, core.INS_HISTORY_DTYPE)
    assert bracket(hist["t_s"], 0, 0, 1.0) == (-1, -1, 0.0)
