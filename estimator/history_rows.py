"""Reading ins's state history (the ring of rows `ins_core` keeps for fusing late fixes) from Python at a fix's time:
the two rows that bracket it, as the kernel reads them (`ins_core._history_at`).

The kernel writes a row only for a sample whose time is after the previous row's (`kernel_flags.step_dt`: a
repeated or backwards time propagates over 0 and writes none) and starts the ring again at a restart
(`ins_start.first_history_row`), so the kept rows' times strictly increase from the oldest to the newest. A
binary search over them then finds what the kernel's walk back from the newest row finds: read per fix, it does not
index every kept row (up to H_LEN) as a mask over them all would.
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
