"""What a filter step reports, for the compiled kernels of both filters (`mekf_core`, `ins_core`): the
EstimateFlags bits as plain ints, the kernels' own result bits, and the checks that set them (which sensors
of a sample may be used, the step's Δt, whether the filter is still initialising).

The flag values come from `core.estimate.EstimateFlags`, the one definition; numba freezes module-level ints
into the compiled code, so a kernel tests and sets them as constants.
"""

from __future__ import annotations

import math

from numba import njit

from ahrsd.core.estimate import EstimateFlags
from ahrsd.core.sample import SampleFlags

F_INITIALISING = int(EstimateFlags.INITIALISING)
F_MAG_REJECTED = int(EstimateFlags.MAG_REJECTED)
F_ACCEL_REJECTED = int(EstimateFlags.ACCEL_REJECTED)
F_AT_REST = int(EstimateFlags.AT_REST)
F_MAG_UNAVAILABLE = int(EstimateFlags.MAG_UNAVAILABLE)
F_LARGE_DT = int(EstimateFlags.LARGE_DT)
F_REINITIALISED = int(EstimateFlags.REINITIALISED)
F_GNSS_AIDED = int(EstimateFlags.GNSS_AIDED)
F_GNSS_OUTAGE = int(EstimateFlags.GNSS_OUTAGE)

# kernel results above every EstimateFlags bit (the caller strips them before building EstimateFlags)
NEEDS_INIT = 1 << 16   # the caller must (re-)initialise from this sample (the step changed nothing)
BAD_SHAPE = 1 << 17    # a vector of the sample does not have 3 elements (the step changed nothing)
assert NEEDS_INIT > max(EstimateFlags)

# input validity: a sensor is used when its SampleFlags bits below are clear and its values are finite
IN_GYRO_OK = 1
IN_ACC_OK = 2
IN_MAG_OK = 4
GYRO_BAD_BITS = int(SampleFlags.GYRO_INVALID | SampleFlags.GYRO_SATURATED)
ACC_BAD_BITS = int(SampleFlags.ACCEL_INVALID | SampleFlags.ACCEL_SATURATED)
MAG_BAD_BITS = int(SampleFlags.MAG_INVALID | SampleFlags.MAG_SATURATED)


@njit(cache=True)
def input_validity(sample_flags, gx, gy, gz, ax, ay, az, mx, my, mz):
    """IN_*_OK bits: which sensors of a sample may be used (driver flags clear and values finite)."""
    valid = 0
    if not (sample_flags & GYRO_BAD_BITS) and math.isfinite(gx + gy + gz):
        valid |= IN_GYRO_OK
    if not (sample_flags & ACC_BAD_BITS) and math.isfinite(ax + ay + az):
        valid |= IN_ACC_OK
    # an all-zero field is no field (a magnetometer that stopped answering): it has no direction to use
    if not (sample_flags & MAG_BAD_BITS) and math.isfinite(mx + my + mz) and mx * mx + my * my + mz * mz > 1e-12:
        valid |= IN_MAG_OK
    return valid


@njit(cache=True)
def step_dt(dt, large_dt, reinit_dt):
    """(Δt to propagate over, flag bits) for a sample Δt after the previous one: LARGE_DT when Δt ≤ 0 or
    > large_dt; NEEDS_INIT as well when Δt > reinit_dt; a repeated or backwards time propagates over 0."""
    flags = 0
    if not (dt > 0.0) or dt > large_dt:
        flags |= F_LARGE_DT
        if dt > reinit_dt:
            return dt, flags | NEEDS_INIT
        if not (dt > 0.0):
            dt = 0.0  # repeated or backwards time: update without propagating
    return dt, flags


@njit(cache=True)
def initialising(t_run, sig_roll, sig_pitch, sig_yaw, min_time, conv_tilt, with_heading, conv_yaw):
    """INITIALISING: less than min_time since (re-)initialisation, or the 1σ tilt (or, with a magnetometer,
    heading) not yet below its convergence threshold."""
    return t_run < min_time or max(sig_roll, sig_pitch) > conv_tilt or (with_heading and sig_yaw > conv_yaw)
