"""The magnetometer heading measurement with its disturbance rejection, shared by `mekf` and `ins` (numba).

Given the field already rotated into the estimated NED frame, decides whether it is undisturbed and, if so,
returns the heading innovation and its noise; the caller applies the update to its own error state (the
heading component only, gain on tilt forced to zero). The field is checked against a learned reference
(magnitude, dip), rejected while it differs, and a consistently changed field is adopted after enough
rotation (VQF's magnetic disturbance rejection: D. Laidig, T. Seel, "VQF: Highly accurate IMU orientation
estimation with bias estimation and magnetic disturbance rejection", Information Fusion 91, 2023, §IV-D);
after too long a rejection the field is used again with 100× the noise; an innovation gate in σ guards the
rest.

The state it keeps lives in a block of the caller's flat state array starting at `s0` (layout `MS_*`), its
parameters in a block of the caller's parameter array starting at `p0` (layout `MP_*`), so both filters run
the same code on their own arrays.
"""

from __future__ import annotations

import math

from numba import njit

# state block (offsets from s0)
MS_REF_NORM = 0     # reference field magnitude, µT (0 = learn from the next sample)
MS_REF_DIP = 1      # reference dip (inclination, positive down), rad
MS_CAND_NORM = 2    # candidate new field magnitude, µT
MS_CAND_DIP = 3     # candidate new field dip, rad
MS_CAND_T = 4       # time the candidate has been consistent while rotating, s
MS_UNDIST_T = 5     # time the field has matched the reference, s
MS_LAST_T = 6       # time since the last accepted heading update, s
MS_DIST_T = 7       # time the field has been continuously disturbed, s
MS_GATE_OPEN_T = 8  # the innovation gate stays open this much longer (new calibration), s
MS_SIZE = 9

# parameter block (offsets from p0)
MP_NOISE = 0               # magnetometer noise per axis, µT
MP_HEADING_NOISE = 1       # heading noise floor in motion, rad
MP_NORM_TOL = 2            # relative field-magnitude tolerance against the reference
MP_DIP_TOL = 3             # dip tolerance against the reference, rad
MP_MIN_UNDIST = 4          # the field must match this long before it is used, s
MP_NEW_TIME = 5            # a consistent new field is adopted after this much rotation time, s
MP_NEW_MIN_RATE = 6        # rotation counts towards MP_NEW_TIME only above this rate, rad/s
MP_REF_TAU = 7             # time constant of the reference's tracking, s
MP_GATE = 8                # innovation gate, σ
MP_UNAVAILABLE = 9         # no heading update for this long → MAG_UNAVAILABLE, s
MP_REJECT_MAX = 10         # after this long continuously disturbed, use the field with 100× the noise, s
MP_HEADING_NOISE_REST = 11  # heading noise floor at rest, rad
MP_SIZE = 12

# result of heading_measurement
MAG_NONE = 0       # no usable field (zero magnitude): nothing to do, no flag
MAG_REJECTED = 1   # disturbed or gated out: flag MAG_REJECTED
MAG_USE = 2        # apply the update with the returned innovation and variance

_TWO_PI = 2.0 * math.pi


@njit(cache=True)
def rotate_to_ned(q0, q1, q2, q3, x, y, z):
    """C_b^n(q) · [x, y, z] for the body→NED quaternion q (Hamilton, scalar first)."""
    n = (1.0 - 2.0 * (q2 * q2 + q3 * q3)) * x + 2.0 * (q1 * q2 - q0 * q3) * y + 2.0 * (q1 * q3 + q0 * q2) * z
    e = 2.0 * (q1 * q2 + q0 * q3) * x + (1.0 - 2.0 * (q1 * q1 + q3 * q3)) * y + 2.0 * (q2 * q3 - q0 * q1) * z
    d = 2.0 * (q1 * q3 - q0 * q2) * x + 2.0 * (q2 * q3 + q0 * q1) * y + (1.0 - 2.0 * (q1 * q1 + q2 * q2)) * z
    return n, e, d


@njit(cache=True)
def heading_measurement(state, s0, par, p0, dt, rate, at_rest, moved_at_rest, mn, me, md, mnorm,
                        declination, heading_var):
    """Check one field sample (mn, me, md: the field in the estimated NED frame, µT; mnorm its magnitude) and
    form the heading measurement. Returns (MAG_*, innovation rad, variance rad²).

    The innovation is the angle of the horizontal field in the estimated frame minus `declination` (0 for a
    filter whose frame is magnetic north), i.e. −δθ_D: the caller applies it with the row h = −e_D.
    rate: bias-corrected angular rate magnitude (rad/s); at_rest / moved_at_rest: from the caller's rest
    detector (a field that moves at rest is a disturbance); heading_var: the filter's heading variance (rad²)
    for the innovation gate."""
    if mnorm <= 1e-6:
        return MAG_NONE, 0.0, 0.0
    mh = math.sqrt(mn * mn + me * me)
    dip = math.atan2(md, mh)
    ref_norm = state[s0 + MS_REF_NORM]
    if ref_norm <= 0.0:
        state[s0 + MS_REF_NORM] = mnorm
        state[s0 + MS_REF_DIP] = dip
        state[s0 + MS_CAND_NORM] = mnorm
        state[s0 + MS_CAND_DIP] = dip
        ref_norm = mnorm
    tol = par[p0 + MP_NORM_TOL]
    dtol = par[p0 + MP_DIP_TOL]
    matches = abs(mnorm - ref_norm) < tol * ref_norm and abs(dip - state[s0 + MS_REF_DIP]) < dtol
    if matches:
        state[s0 + MS_UNDIST_T] += dt
        state[s0 + MS_DIST_T] = 0.0
    else:
        state[s0 + MS_UNDIST_T] = 0.0
        state[s0 + MS_DIST_T] += dt
    # candidate for a new (permanently changed) field: must stay consistent while the body rotates
    cn = state[s0 + MS_CAND_NORM]
    if abs(mnorm - cn) < tol * cn and abs(dip - state[s0 + MS_CAND_DIP]) < dtol:
        kc = 1.0 - math.exp(-dt / par[p0 + MP_REF_TAU]) if dt > 0.0 else 0.0
        state[s0 + MS_CAND_NORM] += kc * (mnorm - cn)
        state[s0 + MS_CAND_DIP] += kc * (dip - state[s0 + MS_CAND_DIP])
        if rate > par[p0 + MP_NEW_MIN_RATE]:
            state[s0 + MS_CAND_T] += dt
    else:
        state[s0 + MS_CAND_NORM] = mnorm
        state[s0 + MS_CAND_DIP] = dip
        state[s0 + MS_CAND_T] = 0.0
    if (not matches) and state[s0 + MS_CAND_T] >= par[p0 + MP_NEW_TIME]:
        # the field has changed for good (new place, new iron): adopt it
        state[s0 + MS_REF_NORM] = state[s0 + MS_CAND_NORM]
        state[s0 + MS_REF_DIP] = state[s0 + MS_CAND_DIP]
        state[s0 + MS_UNDIST_T] = par[p0 + MP_MIN_UNDIST]
        state[s0 + MS_DIST_T] = 0.0
        matches = True
    undisturbed = matches and state[s0 + MS_UNDIST_T] >= par[p0 + MP_MIN_UNDIST] and not moved_at_rest
    inflate = 1.0
    if not undisturbed and state[s0 + MS_DIST_T] > par[p0 + MP_REJECT_MAX]:
        undisturbed = True  # disturbed for too long: use it, but trust it little
        inflate = 100.0
    if not (undisturbed and mh > 1e-3 * mnorm):
        return MAG_REJECTED, 0.0, 0.0
    if matches and dt > 0.0:
        kr = 1.0 - math.exp(-dt / par[p0 + MP_REF_TAU])
        state[s0 + MS_REF_NORM] += kr * (mnorm - state[s0 + MS_REF_NORM])
        state[s0 + MS_REF_DIP] += kr * (dip - state[s0 + MS_REF_DIP])
    # heading measurement: angle of the horizontal field in the estimated NED frame, α = −δθ_D
    alpha = math.atan2(me, mn) - declination
    if alpha > math.pi:
        alpha -= _TWO_PI
    elif alpha < -math.pi:
        alpha += _TWO_PI
    sig_a = par[p0 + MP_NOISE] / mh
    floor = par[p0 + MP_HEADING_NOISE_REST] if at_rest else par[p0 + MP_HEADING_NOISE]
    r = (sig_a * sig_a + floor * floor) * inflate
    s = heading_var + r
    gate_open = state[s0 + MS_GATE_OPEN_T] > 0.0   # after a calibration change (relearn_reference)
    if alpha * alpha > par[p0 + MP_GATE] ** 2 * s and inflate == 1.0 and not gate_open:
        return MAG_REJECTED, 0.0, 0.0
    return MAG_USE, alpha, r


@njit(cache=True)
def heading_bookkeeping(state, s0, par, p0, dt, used):
    """After the step: count down the open gate, time since the last heading update. Returns True when the
    heading has gone without an update for longer than MP_UNAVAILABLE (flag MAG_UNAVAILABLE)."""
    if state[s0 + MS_GATE_OPEN_T] > 0.0:
        state[s0 + MS_GATE_OPEN_T] = max(0.0, state[s0 + MS_GATE_OPEN_T] - dt)
    if used:
        state[s0 + MS_LAST_T] = 0.0
        return False
    state[s0 + MS_LAST_T] += dt
    return state[s0 + MS_LAST_T] > par[p0 + MP_UNAVAILABLE]


def relearn_reference(state, s0, gate_open_s: float) -> None:
    """Forget the learned field reference (the next sample sets it again) and open the innovation gate for
    `gate_open_s` (a new magnetometer calibration may move the heading by more than the gate)."""
    for k in (MS_REF_NORM, MS_REF_DIP, MS_CAND_NORM, MS_CAND_DIP, MS_CAND_T, MS_UNDIST_T, MS_DIST_T):
        state[s0 + k] = 0.0
    state[s0 + MS_GATE_OPEN_T] = gate_open_s
