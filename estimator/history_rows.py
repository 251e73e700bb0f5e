"""Reading ins's state history (the ring of rows `ins_core` keeps for fusing late fixes) from Python at a fix's time:
the two rows that bracket it, as the kernel reads them (`ins_core._history_at`), and the rows within a span about it.

The kernel writes a row only for a sample whose time is after the previous row's (`kernel_flags.step_dt`: a
repeated or backwards time propagates over 0 and writes none) and starts the ring again at a restart
(`ins_start.first_history_row`), so the kept rows' times strictly increase from the oldest to the newest. A
binary search over them then finds what the kernel's walk back from the newest row finds, and a span about a time
is one run of rows: read per fix, neither indexes every kept row (up to H_LEN) as a mask over them all would.
"""

from __future__ import annotations

import numpy as np


def rows_at_or_before(t_rows_s: np.ndarray, newest: int, count: int, t_s: float) -> int:
    """How many of the kept rows (the `count` rows up to ring index `newest` of the ring's row times `t_rows_s`) have
    a time at or before t_s (0 for a NaN t_s)."""
    if not t_s == t_s:
        return 0
    # the kept rows are at most two runs of the ring, each in increasing time: one C search in each (a binary
    # search of its own, as a Python loop over the ring would be, at a fraction of the per-step indexing's cost)
    oldest = newest - count + 1
    if oldest >= 0:
        return int(t_rows_s[oldest:newest + 1].searchsorted(t_s, "right"))
    older = t_rows_s[oldest + len(t_rows_s):]             # the oldest rows, at the ring's end
    k = int(older.searchsorted(t_s, "right"))
    if k < len(older):
        return k
    return k + int(t_rows_s[:newest + 1].searchsorted(t_s, "right"))


def bracket(t_rows_s: np.ndarray, newest: int, count: int, t_s: float) -> tuple[int, int, float]:
    """Ring indices (older, newer) and the weight of the newer row for t_s, as `ins_core._history_at` gives them:
    (newest, newest, 1.0) at or after the newest row, (−1, −1, 0.0) before the oldest (or with no row)."""
    if count == 0:
        return -1, -1, 0.0
    if t_s >= t_rows_s[newest]:
        return newest, newest, 1.0
    k = rows_at_or_before(t_rows_s, newest, count, t_s)
    if k == 0:
        return -1, -1, 0.0
    ring = len(t_rows_s)
    j = (newest - count + k) % ring
    i = (j + 1) % ring
    tj = t_rows_s[j]
    return j, i, float((t_s - tj) / (t_rows_s[i] - tj))


def rows_near(t_rows_s: np.ndarray, newest: int, count: int, t_s: float, half_span_s: float) -> np.ndarray:
    """Ring indices, newest first, of the kept rows around t_s: every row with |t − t_s| ≤ half_span_s and at most a
    few more on either side (the caller applies its own test to these; those it keeps are in the order a mask over
    all kept rows, newest first, gives)."""
    lo = max(rows_at_or_before(t_rows_s, newest, count, t_s - half_span_s) - 2, 0)
    hi = min(rows_at_or_before(t_rows_s, newest, count, t_s + half_span_s) + 2, count)
    if hi <= lo:
        return np.zeros(0, dtype=np.intp)
    oldest = newest - count + 1
    return (oldest + np.arange(hi - 1, lo - 1, -1)) % len(t_rows_s)
