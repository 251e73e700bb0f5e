"""The lever-arm check's innovation at a fix (lever_arm_fit.py), compiled: what `InsGnssFusion` reads of ins's state
history for each velocity fix, in one call instead of some twenty numpy calls on 3-vectors and 3 × 3 matrices.

From the history rows (ins_core's ring as flat float64 rows) at the fix's time of validity t: the two rows that
bracket t as the filter's kernel finds them (`ins_core.history_bracket`, the kernel's own), interpolated as
`InsGnssFusion.state_at` does (a + w (b − a)); the attitude normalised (√ of the quaternion's dot with itself) and
made a DCM (kernel_rotations.dcm: quat_to_dcm's products and sums); the body rate the mean of the rows within
RATE_MEAN_S about t (added newest first from +0.0, then divided by their count; the interpolated rate when none is);
C [ω×] and the innovation v_fix − (v + C [ω×] r).

Output-identical to that Python, to the bit: the element-wise arithmetic is the same operations in the same order
(numba fuses no multiply-add unless asked, `fastmath` off), and the products numpy hands to BLAS (the quaternion's
dot, C @ [ω×], C [ω×] @ r) are numba's `np.dot` and `@`, which call the same OpenBLAS kernels (scipy's copy of the
library numpy bundles), whose fused multiply-adds a sum written out here would not reproduce
(tools/estimate_digest.py: the same digests; test_lever_arm_kernel.py: the kernel against that Python, kept as
tests/lever_arm_reference.py, on random history rings).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from . import ins_core as core
from .kernel_rotations import dcm

# where each field lies in a history row's flat float64 view (every field is float64: filter_output.float_field_slice)
_T = core.INS_HISTORY_DTYPE.fields["t_s"][1] // 8
_Q = core.INS_HISTORY_DTYPE.fields["q"][1] // 8
_VEL = core.INS_HISTORY_DTYPE.fields["vel_ned_m_s"][1] // 8
_RATE = core.INS_HISTORY_DTYPE.fields["rate_rad_s"][1] // 8


@njit(cache=True)
def fix_innovation(rows, newest, count, t_s, v_fix_ned_m_s, arm_m, half_span_s):
    """The lever-arm check's terms for a velocity fix of time t_s (v_fix_ned_m_s: NED m/s, vertical NaN when not
    used) at the antenna arm arm_m (body FRD, m), from the `count` kept history rows up to ring index `newest` of
    `rows` (H_LEN × the row's floats): (found, innovation NED m/s, C [ω×], the interpolated velocity NED m/s), the
    body rate the mean of the rows within half_span_s of t_s. found False (and zeros) when t_s is older than every
    kept row or there is none."""
    ring = rows.shape[0]
    # the bracket the filter's kernel finds for a fix (ins_core._history_at), on the rows' time column
    i0, i1, w = core.history_bracket(rows[:, _T], newest, count, t_s)
    vel = np.zeros(3)
    rate_cross = np.zeros((3, 3))
    if i0 < 0:
        return False, np.zeros(3), rate_cross, vel
    row = rows[i0] + w * (rows[i1] - rows[i0])
    q = row[_Q:_Q + 4]
    q = q / math.sqrt(np.dot(q, q))
    c = dcm(q[0], q[1], q[2], q[3])
    c_bn = np.empty((3, 3))
    for k in range(9):
        c_bn[k // 3, k % 3] = c[k]
    vel[:] = row[_VEL:_VEL + 3]
    # the mean body rate: the rows within the span, newest first (the order the Python's mask gave them in)
    n = 0
    sx = sy = sz = 0.0
    i = newest
    for _ in range(count):
        d = rows[i, _T] - t_s
        if abs(d) <= half_span_s:
            sx += rows[i, _RATE]
            sy += rows[i, _RATE + 1]
            sz += rows[i, _RATE + 2]
            n += 1
        elif d < 0.0:
            break           # older than the span: so is every row before it
        i = (i - 1) % ring
    if n:
        wx, wy, wz = sx / n, sy / n, sz / n
    else:
        wx, wy, wz = row[_RATE], row[_RATE + 1], row[_RATE + 2]
    skew = np.zeros((3, 3))
    skew[0, 1], skew[0, 2] = -wz, wy
    skew[1, 0], skew[1, 2] = wz, -wx
    skew[2, 0], skew[2, 1] = -wy, wx
    rate_cross = c_bn @ skew
    innovation = v_fix_ned_m_s - (vel + rate_cross @ arm_m)
    return True, innovation, rate_cross, vel
