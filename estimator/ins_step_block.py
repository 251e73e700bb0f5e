"""ins's step over a run of samples in one compiled call: the daemon's samples arrive in blocks (about 12 at 819.2
SPS, one per output deadline), and between two samples of a block ins's Python has nothing to do most of the time —
only a queued fix falling due (fused from Python), a sample that needs the filter (re)started, the start's
recording and the field-circle check before the first fix do. `ins_step_block` runs `ins_core.ins_step` and the
published heading's slew (published_heading.published_offset_step, which follows every sample) over the samples up
to the first of those, so the per-sample call into the kernel, its eighteen arguments, the sample's nine floats read
out of numpy arrays and the slew's Python are paid once a run instead of once a sample (Ins.step_block).
"""

from __future__ import annotations

from numba import njit

from .ins_core import ins_step
from .kernel_entry import argument_types, entry_point
from .kernel_flags import F_INITIALISING, NEEDS_INIT
from .published_heading import FOLLOWING, published_offset_step


@njit(cache=True)
def ins_step_block(state, P, hist, params, t_s, rows, sample_flags, stop_t_s, out, gsf, gsf_par, step_flags,
                   published, published_rate_rad_s):
    """Samples k = 0, 1, … of t_s (n,), rows (n, 9: gyro rad/s, accel m/s², mag µT) and sample_flags (n,) through
    `ins_step`, in order, each stepped sample's returned flags kept in step_flags[k]; after each, the published
    heading's state (`published`, PublishedHeading.state; its slew rate `published_rate_rad_s`) stepped from the
    sample's outputs as Ins._after_step steps it (once the filter's estimates are followed: from the first sample not
    INITIALISING since the start). Stops before the first sample at or after stop_t_s (a queued fix is due there:
    the caller steps it alone and fuses the fix after it, as `Ins.step` does), before one whose step says NEEDS_INIT
    (ins_step changed nothing then: the caller initialises from it) and when step_flags is full. Returns the number
    of samples stepped."""
    n = min(t_s.shape[0], step_flags.shape[0])
    o = out[0]
    k = 0
    while k < n:
        t = t_s[k]
        if t >= stop_t_s:
            break
        r = rows[k]
        f = ins_step(state, P, hist, params, t, r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8],
                     sample_flags[k], out, gsf, gsf_par)
        if f & NEEDS_INIT:
            break
        if published[FOLLOWING] > 0.0 or not f & F_INITIALISING:
            published_offset_step(published, published_rate_rad_s, t, o.euler_rad[2], o.euler_rad[0], o.euler_rad[1],
                                  o.rate_rad_s[1], o.rate_rad_s[2], o.sigma_rpy_rad[2])
            published[FOLLOWING] = 1.0
        step_flags[k] = f
        k += 1
    return k


def fast_step_block(example_args):
    """`ins_step_block` compiled for the types of `example_args`, as that overload's entry point (kernel_entry.py:
    the caller passes exactly these types)."""
    return entry_point(ins_step_block, argument_types(ins_step_block, example_args))
