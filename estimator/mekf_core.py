"""The MEKF's per-sample step, compiled with numba (the one implementation of the algorithm).

`mekf.py` owns the parameters, initialisation (weighted Wahba) and the Estimator interface; this module is
the hot path: strapdown propagation, covariance propagation, rest detection, gated accelerometer (tilt) and
magnetometer (heading) updates. Everything works on two flat float64 arrays — `state` (layout `S_*`) and
`par` (layout `P_*`, filled from `MekfParams`) — so a step allocates nothing and one numba call serves a
sample. `mekf_run` loops the same `mekf_step` over arrays for replay and benchmarks.

Error state (6): δθ, the attitude error in the NED frame (C_true = (I + [δθ×]) C_est), and δb, the gyro bias
error (b_true = b_est + δb). Tilt is δθ_N, δθ_E; heading is δθ_D. The accelerometer observes only
δθ_N, δθ_E and the magnetometer only δθ_D (their measurement rows), and their gains on the other attitude
components are forced to zero (Joseph-form covariance), so neither can move what it does not observe
through the covariance's cross terms: a magnetic disturbance cannot move the horizon, linear acceleration
cannot move the heading.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numba.core import cgutils
from numba.extending import intrinsic

from ahrsd.core.sample import SampleFlags

from . import mag_heading as mag

# ----------------------------------------------------------------------------------- state layout
S_Q = 0            # 4: attitude quaternion body→NED, scalar first
S_B = 4            # 3: gyro bias, rad/s
S_P = 7            # 36: error covariance 6×6 row-major [δθ (rad), δb (rad/s)]
S_T_LAST = 43      # time of the previous sample, s
S_GYR_LP = 44      # 3: low-passed gyro for rest detection, rad/s
S_ACC_LP = 47      # 3: low-passed accelerometer for rest detection, m/s²
S_REST_T = 50      # time the rest conditions have held, s
# (slots 51–57, 66 and 78 unused: the magnetometer's state moved to the S_MAG block)
S_G_REF = 58          # gravity magnitude learned at rest, m/s²
S_ACC_I = 59          # 3: specific force low-passed in the NED frame, m/s²
S_GYR_LAST = 62       # 3: last valid gyro sample, rad/s
S_T_RUN = 65          # time since initialisation, s
S_ACC_REJ_T = 67      # time since the last accepted tilt update, s
S_MAG_LP = 68         # 3: low-passed body-frame field (rest filter), µT
S_MAG_REST = 71       # 3: body-frame field when the current rest began, µT
S_MAG_REST_SET = 74   # 1.0 while S_MAG_REST holds this rest's field
S_REST_DG = 75        # low-passed squared gyro deviation from its low-pass, (rad/s)²
S_REST_DA = 76        # low-passed squared acc deviation, (m/s²)²
S_ACC_HOLD_T = 77     # tilt updates stay off this much longer after a sustained push, s
S_MAG = 80            # 9: the magnetometer heading check's state (mag_heading.MS_*)
S_MAG_REF_NORM = S_MAG + mag.MS_REF_NORM    # reference field magnitude, µT (0 = not yet learned)
S_MAG_REF_DIP = S_MAG + mag.MS_REF_DIP      # reference dip (inclination, positive down), rad
S_MAG_CAND_NORM = S_MAG + mag.MS_CAND_NORM  # candidate new field magnitude, µT
S_MAG_CAND_DIP = S_MAG + mag.MS_CAND_DIP    # candidate new field dip, rad
S_MAG_CAND_T = S_MAG + mag.MS_CAND_T        # time the candidate has been consistent while rotating, s
S_MAG_UNDIST_T = S_MAG + mag.MS_UNDIST_T    # time the field has matched the reference, s
S_MAG_LAST_T = S_MAG + mag.MS_LAST_T        # time since the last accepted heading update, s
S_MAG_DIST_T = S_MAG + mag.MS_DIST_T        # time the field has been continuously disturbed, s
S_MAG_GATE_OPEN_T = S_MAG + mag.MS_GATE_OPEN_T  # the heading gate stays open this much longer (new calibration), s
# after the magnetometer block, each slot following the one before by its size
S_ACC_NU_MEAN = S_MAG + mag.MS_SIZE  # 2: running mean of the tilt innovation (north, east), rad
S_ACC_NU_VAR = S_ACC_NU_MEAN + 2     # 2: running mean square deviation of the tilt innovation from it, rad²
S_MOFF_B = S_ACC_NU_VAR + 2          # 3: estimated body-fixed field offset (magnet attached after calibration), µT
S_MOFF_P = S_MOFF_B + 3              # 9: its covariance 3×3 row-major, µT²
S_MOFF_CM = S_MOFF_P + 9             # 3: C·m (field in the estimated NED frame) at the previous snapshot, µT
S_MOFF_C = S_MOFF_CM + 3             # 9: C_b^n at the previous snapshot
S_MOFF_T = S_MOFF_C + 9              # time since the previous snapshot, s
S_MOFF_SET = S_MOFF_T + 1            # 1.0 when the previous snapshot is valid
S_MOFF_NIS = S_MOFF_SET + 1          # running mean of the offset fit's normalised squared innovation (fit)
S_MOFF_D_RAW = S_MOFF_NIS + 1        # running mean of the raw field's disagreement with the reference (_disagreement)
S_MOFF_D_COR = S_MOFF_D_RAW + 1      # ... of the offset-corrected field's
S_MOFF_DIP_AT = S_MOFF_D_COR + 1     # 3: the reference dip, rad, its sine and cosine (cached for _disagreement)
S_MOFF_READY = S_MOFF_DIP_AT + 3     # 1.0 while the estimate is known well enough, significant and consistent
S_LPW = S_MOFF_READY + 1             # 10: cached low-pass weights (Δt, 1 − exp(−Δt/τ)): rest, NED acc, spread, g,
S_SIZE = S_LPW + 10                  # field disagreement

# ----------------------------------------------------------------------------------- parameter layout
P_GYRO_NOISE = 0        # gyro angle random walk, rad/s/√Hz
# (slot 1 unused)
P_BIAS_WALK = 2         # gyro bias random walk, rad/s/√s
P_BIAS_CLIP = 3         # |bias| limit per axis, rad/s
P_ACC_NOISE = 4         # accelerometer noise in motion (includes typical linear acceleration), m/s²
P_ACC_NOISE_REST = 5    # accelerometer noise at rest, m/s²
P_ACC_TURN_GAIN = 6     # tilt noise per rad of the turn angle acos(g/|f|), dimensionless
P_ACC_REJECT = 7        # reject the accelerometer when | |f| − g | exceeds this, m/s²
P_ACC_GATE = 8          # tilt innovation gate (angle between measured and estimated vertical), rad
P_ACC_TAU = 9           # time constant of the NED-frame low-pass of the specific force, s (0 = off)
# (slots 10–19, 31, 32 unused: the magnetometer's parameters moved to the P_MAG block)
P_REST_GYRO_TH = 20     # rest: gyro deviation from its low-pass below this, rad/s
P_REST_ACC_TH = 21      # rest: acc deviation from its low-pass below this, m/s²
P_REST_MIN_T = 22       # rest declared after the conditions held this long, s
P_REST_TAU = 23         # low-pass time constant for rest detection, s
P_REST_BIAS_NOISE = 24  # floor of the gyro noise density used for bias measurements at rest, rad/s/√Hz
P_LARGE_DT = 25         # Δt above this (or ≤ 0) is flagged LARGE_DT, s
P_REINIT_DT = 26        # Δt above this re-initialises the filter, s
P_INIT_TIME = 27        # INITIALISING is held at least this long, s
P_CONV_TILT = 28        # ... and until 1σ tilt is below this, rad
P_CONV_YAW = 29         # ... and 1σ yaw below this, rad
P_MAG_ENABLED = 30      # 1.0 = use the magnetometer, 0.0 = 6-axis (heading from gyro only)
P_ACC_GATE_RECOVER = 33  # after this long without a tilt update, rejection is overridden (recovery), s
P_ACC_TURN_DEAD = 34    # turn angles below this add no noise, rad
P_MAG_REST_CHANGE = 35  # at rest, a low-passed body-frame field change above this is a disturbance, µT
P_MAG = 36              # 12: the magnetometer heading check's parameters (mag_heading.MP_*)
P_MAG_NOISE = P_MAG + mag.MP_NOISE                # magnetometer noise per axis, µT
P_MAG_HEADING_NOISE = P_MAG + mag.MP_HEADING_NOISE  # heading noise floor (residual calibration, local field), rad
P_MAG_NORM_TOL = P_MAG + mag.MP_NORM_TOL          # relative field-magnitude tolerance against the reference
P_MAG_DIP_TOL = P_MAG + mag.MP_DIP_TOL            # dip-angle tolerance against the reference, rad
P_MAG_MIN_UNDIST = P_MAG + mag.MP_MIN_UNDIST      # the field must match the reference this long before use, s
P_MAG_NEW_TIME = P_MAG + mag.MP_NEW_TIME          # a consistent new field is accepted after this rotation time, s
P_MAG_NEW_MIN_RATE = P_MAG + mag.MP_NEW_MIN_RATE  # rotation counts towards P_MAG_NEW_TIME only above this, rad/s
P_MAG_REF_TAU = P_MAG + mag.MP_REF_TAU            # time constant of the reference field's tracking, s
P_MAG_GATE = P_MAG + mag.MP_GATE                  # heading innovation gate, in σ
P_MAG_UNAVAILABLE = P_MAG + mag.MP_UNAVAILABLE    # no heading update for this long → MAG_UNAVAILABLE, s
P_MAG_REJECT_MAX = P_MAG + mag.MP_REJECT_MAX      # disturbed this long: field trusted again, inflated noise, s
P_MAG_HEADING_NOISE_REST = P_MAG + mag.MP_HEADING_NOISE_REST  # heading noise floor at rest, rad
# after the magnetometer block, one slot each
P_ACC_ADAPT_GAIN = P_MAG + mag.MP_SIZE  # tilt variance added per unit of the tilt innovation's spread
P_ACC_ADAPT_TAU = P_ACC_ADAPT_GAIN + 1  # window (time constant) of the innovation's running mean, spread, s (0 = off)
P_GYRO_RATE_NOISE = P_ACC_ADAPT_TAU + 1  # attitude process noise per rad/s of rate (gyro scale/alignment errors), √s
P_MOFF_TAU = P_GYRO_RATE_NOISE + 1      # forgetting time constant of the body-fixed offset estimate, s (0 = off)
P_MOFF_MIN_COS = P_MOFF_TAU + 1         # snapshots are compared once the body has turned this far: its cosine
P_MOFF_USE_SIGMA = P_MOFF_MIN_COS + 1    # the offset is subtracted once its 1σ (largest axis) is below this, µT
P_MOFF_LAG = P_MOFF_USE_SIGMA + 1       # magnetometer–gyro timing skew: |ω|·this·|m| of noise per fit row, s
P_MOFF_AGREE_TAU = P_MOFF_LAG + 1       # time constant of the running field disagreement, s
P_MOFF_EXPLAIN = P_MOFF_AGREE_TAU + 1   # the offset is used while the corrected field's disagreement is below
                                        # this fraction of the raw field's
P_SIZE = P_MOFF_EXPLAIN + 1

# ----------------------------------------------------------------------------------- flags (= EstimateFlags)
F_INITIALISING = 1
F_MAG_REJECTED = 2
F_ACCEL_REJECTED = 4
F_AT_REST = 8
F_MAG_UNAVAILABLE = 16
F_LARGE_DT = 32
F_REINITIALISED = 64
# error-state component masks for _scalar_update's zero_mask
M_TILT = 1 | 2
M_HEADING = 4
M_BIAS = 8 | 16 | 32
# step result: the caller must (re-)initialise from this sample (the step changed nothing)
NEEDS_INIT = 1 << 16
# one-sample step result: a vector of the sample does not have 3 elements (the step changed nothing)
BAD_SHAPE = 1 << 17

# input validity: a sensor is used when its SampleFlags bits below are clear and its values are finite
IN_GYRO_OK = 1
IN_ACC_OK = 2
IN_MAG_OK = 4
GYRO_BAD_BITS = int(SampleFlags.GYRO_INVALID | SampleFlags.GYRO_SATURATED)
ACC_BAD_BITS = int(SampleFlags.ACCEL_INVALID | SampleFlags.ACCEL_SATURATED)
MAG_BAD_BITS = int(SampleFlags.MAG_INVALID | SampleFlags.MAG_SATURATED)

# output layout of `out` (per step)
O_Q = 0        # 4
O_RATE = 4     # 3 bias-corrected rate
O_SIGMA = 7    # 3 roll, pitch, yaw 1σ
O_BIAS = 10    # 3 gyro bias
O_EULER = 13   # 3 roll, pitch, yaw (ZYX, yaw magnetic in [−π, π])
O_SIZE = 16


@intrinsic
def borrowed(typingctx, arr):
    """A view of the array `arr` (same data, shape, strides) that holds no reference to its owner (numba's
    meminfo is null), for compiled code only.

    Numba counts references to an array with atomic instructions (`NRT_incref`/`NRT_decref`: a `lock incq`
    each) when a compiled function that receives it starts and returns; its reference-count pruning pass removes
    them only in functions with simple control flow. In the step kernel they stayed in `mekf_step`,
    `_field_offset` and `heading_measurement` (branches, loops, calls passing the array on): about a dozen
    atomic operations per sample, on a null meminfo a test and a jump. Valid only while the owner is alive:
    the entry points borrow their own arguments (which the caller holds for the whole call) and use the
    view only inside that call."""

    def codegen(context, builder, sig, args):
        src = context.make_array(sig.args[0])(context, builder, args[0])
        dst = context.make_array(sig.return_type)(context, builder)
        dst.meminfo = cgutils.get_null_value(dst.meminfo.type)
        dst.parent = cgutils.get_null_value(dst.parent.type)
        dst.nitems = src.nitems
        dst.itemsize = src.itemsize
        dst.data = src.data
        dst.shape = src.shape
        dst.strides = src.strides
        return dst._getvalue()

    return arr(arr), codegen


@njit(cache=True)
def _scalar_update(state, j, sign, nu, r, zero_mask):
    """Kalman update with one scalar measurement whose row is h = sign·e_j (it observes one error-state
    component). Gains of the error-state components whose bit is set in `zero_mask` are forced to zero, so
    this measurement cannot move them (the magnetometer never moves tilt, the accelerometer never heading), and
    the covariance takes the Joseph form, valid for such a constrained gain:
    P ← P − K uᵀ − u Kᵀ + S K Kᵀ with u = P hᵀ, S = h P hᵀ + r.
    Returns the error-state correction K·ν."""
    p0 = S_P
    s = state[p0 + j * 6 + j] + r
    u0 = sign * state[p0 + 0 * 6 + j]
    u1 = sign * state[p0 + 1 * 6 + j]
    u2 = sign * state[p0 + 2 * 6 + j]
    u3 = sign * state[p0 + 3 * 6 + j]
    u4 = sign * state[p0 + 4 * 6 + j]
    u5 = sign * state[p0 + 5 * 6 + j]
    k0 = 0.0 if zero_mask & 1 else u0 / s
    k1 = 0.0 if zero_mask & 2 else u1 / s
    k2 = 0.0 if zero_mask & 4 else u2 / s
    k3 = 0.0 if zero_mask & 8 else u3 / s
    k4 = 0.0 if zero_mask & 16 else u4 / s
    k5 = 0.0 if zero_mask & 32 else u5 / s
    # the 21 entries of the upper triangle, mirrored (the update is symmetric by construction); unrolled:
    # a loop indexing tuples of the gains made the whole batch run 1.7× slower (numba)
    state[p0 + 0] += s * k0 * k0 - 2.0 * k0 * u0
    state[p0 + 1] = state[p0 + 6] = state[p0 + 1] - k0 * u1 - u0 * k1 + s * k0 * k1
    state[p0 + 2] = state[p0 + 12] = state[p0 + 2] - k0 * u2 - u0 * k2 + s * k0 * k2
    state[p0 + 3] = state[p0 + 18] = state[p0 + 3] - k0 * u3 - u0 * k3 + s * k0 * k3
    state[p0 + 4] = state[p0 + 24] = state[p0 + 4] - k0 * u4 - u0 * k4 + s * k0 * k4
    state[p0 + 5] = state[p0 + 30] = state[p0 + 5] - k0 * u5 - u0 * k5 + s * k0 * k5
    state[p0 + 7] += s * k1 * k1 - 2.0 * k1 * u1
    state[p0 + 8] = state[p0 + 13] = state[p0 + 8] - k1 * u2 - u1 * k2 + s * k1 * k2
    state[p0 + 9] = state[p0 + 19] = state[p0 + 9] - k1 * u3 - u1 * k3 + s * k1 * k3
    state[p0 + 10] = state[p0 + 25] = state[p0 + 10] - k1 * u4 - u1 * k4 + s * k1 * k4
    state[p0 + 11] = state[p0 + 31] = state[p0 + 11] - k1 * u5 - u1 * k5 + s * k1 * k5
    state[p0 + 14] += s * k2 * k2 - 2.0 * k2 * u2
    state[p0 + 15] = state[p0 + 20] = state[p0 + 15] - k2 * u3 - u2 * k3 + s * k2 * k3
    state[p0 + 16] = state[p0 + 26] = state[p0 + 16] - k2 * u4 - u2 * k4 + s * k2 * k4
    state[p0 + 17] = state[p0 + 32] = state[p0 + 17] - k2 * u5 - u2 * k5 + s * k2 * k5
    state[p0 + 21] += s * k3 * k3 - 2.0 * k3 * u3
    state[p0 + 22] = state[p0 + 27] = state[p0 + 22] - k3 * u4 - u3 * k4 + s * k3 * k4
    state[p0 + 23] = state[p0 + 33] = state[p0 + 23] - k3 * u5 - u3 * k5 + s * k3 * k5
    state[p0 + 28] += s * k4 * k4 - 2.0 * k4 * u4
    state[p0 + 29] = state[p0 + 34] = state[p0 + 29] - k4 * u5 - u4 * k5 + s * k4 * k5
    state[p0 + 35] += s * k5 * k5 - 2.0 * k5 * u5
    return k0 * nu, k1 * nu, k2 * nu, k3 * nu, k4 * nu, k5 * nu


@njit(cache=True)
def _apply_correction(state, par, dx0, dx1, dx2, dx3, dx4, dx5):
    """q ← exp(δθ) ⊗ q (NED-frame error), b ← b + δb (clipped); rotates the NED low-pass with the frame."""
    hw = 1.0
    hx = 0.5 * dx0
    hy = 0.5 * dx1
    hz = 0.5 * dx2
    n = math.sqrt(hw * hw + hx * hx + hy * hy + hz * hz)
    hw /= n
    hx /= n
    hy /= n
    hz /= n
    qw = state[S_Q]
    qx = state[S_Q + 1]
    qy = state[S_Q + 2]
    qz = state[S_Q + 3]
    nw = hw * qw - hx * qx - hy * qy - hz * qz
    nx = hw * qx + hx * qw + hy * qz - hz * qy
    ny = hw * qy - hx * qz + hy * qw + hz * qx
    nz = hw * qz + hx * qy - hy * qx + hz * qw
    n = math.sqrt(nw * nw + nx * nx + ny * ny + nz * nz)
    state[S_Q] = nw / n
    state[S_Q + 1] = nx / n
    state[S_Q + 2] = ny / n
    state[S_Q + 3] = nz / n
    clip = par[P_BIAS_CLIP]
    state[S_B] = min(max(state[S_B] + dx3, -clip), clip)
    state[S_B + 1] = min(max(state[S_B + 1] + dx4, -clip), clip)
    state[S_B + 2] = min(max(state[S_B + 2] + dx5, -clip), clip)
    # the NED-frame low-passed specific force lives in the estimated NED frame: keep it there
    ax = state[S_ACC_I]
    ay = state[S_ACC_I + 1]
    az = state[S_ACC_I + 2]
    state[S_ACC_I] = ax + dx1 * az - dx2 * ay
    state[S_ACC_I + 1] = ay + dx2 * ax - dx0 * az
    state[S_ACC_I + 2] = az + dx0 * ay - dx1 * ax


@njit(cache=True)
def _running_spread(mean, var, x, k):
    """Running mean of x and running mean square deviation of x from it, both low-passed with weight
    k = 1 − exp(−Δt/τ). Returns (mean, var)."""
    mean += k * (x - mean)
    d = x - mean
    var += k * (d * d - var)
    return mean, var


@njit(cache=True)
def _offset_update(state, c00, c01, c02, c10, c11, c12, c20, c21, c22, cmx, cmy, cmz, r):
    """Recursive least squares for a body-fixed field offset b from two snapshots of the field:
    the earth field is constant in NED, m = C_nᵇ h + b, so C₂m₂ − C₁m₁ = (C₂ − C₁) b (the attitude's heading
    error cancels as long as it is the same at both). Three scalar rows, noise variance r (µT²) each.
    Returns the mean normalised squared innovation of the rows (≈ 1 when the model fits)."""
    nis = 0.0
    cn = (c00, c01, c02, c10, c11, c12, c20, c21, c22)
    y = (cmx - state[S_MOFF_CM], cmy - state[S_MOFF_CM + 1], cmz - state[S_MOFF_CM + 2])
    for i in range(3):
        h0 = cn[3 * i] - state[S_MOFF_C + 3 * i]
        h1 = cn[3 * i + 1] - state[S_MOFF_C + 3 * i + 1]
        h2 = cn[3 * i + 2] - state[S_MOFF_C + 3 * i + 2]
        p = S_MOFF_P
        ph0 = state[p + 0] * h0 + state[p + 1] * h1 + state[p + 2] * h2
        ph1 = state[p + 3] * h0 + state[p + 4] * h1 + state[p + 5] * h2
        ph2 = state[p + 6] * h0 + state[p + 7] * h1 + state[p + 8] * h2
        sv = h0 * ph0 + h1 * ph1 + h2 * ph2 + r
        nu = y[i] - (h0 * state[S_MOFF_B] + h1 * state[S_MOFF_B + 1] + h2 * state[S_MOFF_B + 2])
        nis += nu * nu / sv
        k0 = ph0 / sv
        k1 = ph1 / sv
        k2 = ph2 / sv
        state[S_MOFF_B] += k0 * nu
        state[S_MOFF_B + 1] += k1 * nu
        state[S_MOFF_B + 2] += k2 * nu
        state[p + 0] -= k0 * ph0
        state[p + 1] -= k0 * ph1
        state[p + 2] -= k0 * ph2
        state[p + 3] -= k1 * ph0
        state[p + 4] -= k1 * ph1
        state[p + 5] -= k1 * ph2
        state[p + 6] -= k2 * ph0
        state[p + 7] -= k2 * ph1
        state[p + 8] -= k2 * ph2
    return nis / 3.0


@njit(cache=True)
def _disagreement(state, par, fn, fe, fd):
    """How far a field (in the estimated NED frame, µT) is from the learned reference, in units of the
    disturbance checks' tolerances: ((|m| − ref) / (tol·ref))² + (sin(dip − ref dip) / dip tol)²; > 1 is
    outside. (The sine of the dip difference, from the cached sine and cosine of the reference dip, instead of
    the difference itself: no atan2 per sample, and within 1.2 % of it up to 15°.)"""
    ref = state[S_MAG_REF_NORM]
    ref_dip = state[S_MAG_REF_DIP]
    if state[S_MOFF_DIP_AT + 2] == 0.0 or abs(ref_dip - state[S_MOFF_DIP_AT]) > 1e-3:
        state[S_MOFF_DIP_AT] = ref_dip
        state[S_MOFF_DIP_AT + 1] = math.sin(ref_dip)
        state[S_MOFF_DIP_AT + 2] = math.cos(ref_dip)
    fh = math.sqrt(fn * fn + fe * fe)
    n = math.sqrt(fh * fh + fd * fd)
    dn = (n - ref) / (par[P_MAG_NORM_TOL] * ref)
    dd = (fd * state[S_MOFF_DIP_AT + 2] - fh * state[S_MOFF_DIP_AT + 1]) / (n * par[P_MAG_DIP_TOL])
    return dn * dn + dd * dd


@njit(cache=True)
def _field_offset(state, par, dt, rate, mx, my, mz):
    """Learn and, where it explains the field, remove a body-fixed field offset b (a magnet or iron attached
    after calibration: uncalibrated hard iron). Returns the field to use in the body frame (mx, my, mz) and in
    the estimated NED frame (mn, me, md), µT.

    m = C_nᵇ h + b: the norm and dip of m change with orientation, so the field disagrees with the reference
    learned before the magnet came. b is observable from rotation alone (_offset_update: the heading error
    cancels between two snapshots), learned by recursive least squares forgetting with time constant
    P_MOFF_TAU. A fit also reads the residual calibration errors and the field gradients of an undisturbed
    work space as an offset of a few µT, so b is used only while it explains why the field disagrees with the
    reference: the corrected field's running disagreement (_disagreement, time constant P_MOFF_AGREE_TAU) is
    below P_MOFF_EXPLAIN times the raw field's. An offset that leaves the field's norm and dip as they were is
    not used; nor is one fitted to a magnet in the surroundings (its field depends on position, not on
    orientation, and the fit is inconsistent); when the magnet is removed the raw field agrees again and b is
    no longer used."""
    c00, c01, c02, c10, c11, c12, c20, c21, c22 = _dcm_of_state(state)
    cmx = c00 * mx + c01 * my + c02 * mz
    cmy = c10 * mx + c11 * my + c12 * mz
    cmz = c20 * mx + c21 * my + c22 * mz
    if state[S_MAG_REF_NORM] <= 0.0:
        return mx, my, mz, cmx, cmy, cmz
    kd = _lowpass_weight(state, S_LPW + 8, dt, par[P_MOFF_AGREE_TAU]) if dt > 0.0 else 0.0
    state[S_MOFF_D_RAW] += kd * (_disagreement(state, par, cmx, cmy, cmz) - state[S_MOFF_D_RAW])
    state[S_MOFF_T] += dt
    take = state[S_MOFF_SET] == 0.0 or state[S_MOFF_T] > 2.0
    if state[S_MOFF_SET] != 0.0:
        # rotation between the snapshots: cos θ = (trace(C₁ᵀ C₂) − 1) / 2
        tr = (c00 * state[S_MOFF_C] + c01 * state[S_MOFF_C + 1] + c02 * state[S_MOFF_C + 2]
              + c10 * state[S_MOFF_C + 3] + c11 * state[S_MOFF_C + 4] + c12 * state[S_MOFF_C + 5]
              + c20 * state[S_MOFF_C + 6] + c21 * state[S_MOFF_C + 7] + c22 * state[S_MOFF_C + 8])
        if 0.5 * (tr - 1.0) < par[P_MOFF_MIN_COS]:
            if state[S_MOFF_P] == 0.0:
                for i in range(3):
                    state[S_MOFF_P + 4 * i] = 1e4   # (100 µT)²: nothing known
            lam = math.exp(-state[S_MOFF_T] / par[P_MOFF_TAU])
            for i in range(9):
                state[S_MOFF_P + i] = min(state[S_MOFF_P + i] / lam, 1e4)
            # a magnetometer sampled δt apart from the gyro sees the field turned by |ω|·δt
            lag_ut = rate * par[P_MOFF_LAG] * math.sqrt(mx * mx + my * my + mz * mz)
            nis = _offset_update(state, c00, c01, c02, c10, c11, c12, c20, c21, c22, cmx, cmy, cmz,
                                 2.0 * (par[P_MAG_NOISE] ** 2 + lag_ut * lag_ut))
            state[S_MOFF_NIS] += (1.0 - lam) * (nis - state[S_MOFF_NIS])
            take = True
            # usable: known well enough, significantly non-zero (Σ b²/σ² > 16: not calibration residue within
            # the noise), and the data fit a body-fixed offset (a field that changes with position leaves
            # innovations far above their predicted variance). P and the fit change only here.
            pmax = max(state[S_MOFF_P], max(state[S_MOFF_P + 4], state[S_MOFF_P + 8]))
            signif = 0.0
            for i in range(3):
                signif += state[S_MOFF_B + i] ** 2 / state[S_MOFF_P + 4 * i]
            ok = pmax < par[P_MOFF_USE_SIGMA] ** 2 and signif > 16.0 and state[S_MOFF_NIS] < 4.0
            state[S_MOFF_READY] = 1.0 if ok else 0.0
    if take:
        state[S_MOFF_CM] = cmx
        state[S_MOFF_CM + 1] = cmy
        state[S_MOFF_CM + 2] = cmz
        state[S_MOFF_C] = c00
        state[S_MOFF_C + 1] = c01
        state[S_MOFF_C + 2] = c02
        state[S_MOFF_C + 3] = c10
        state[S_MOFF_C + 4] = c11
        state[S_MOFF_C + 5] = c12
        state[S_MOFF_C + 6] = c20
        state[S_MOFF_C + 7] = c21
        state[S_MOFF_C + 8] = c22
        state[S_MOFF_SET] = 1.0
        state[S_MOFF_T] = 0.0
    if state[S_MOFF_READY] == 0.0:
        state[S_MOFF_D_COR] = state[S_MOFF_D_RAW]
        return mx, my, mz, cmx, cmy, cmz
    bx = state[S_MOFF_B]
    by = state[S_MOFF_B + 1]
    bz = state[S_MOFF_B + 2]
    cbx = cmx - (c00 * bx + c01 * by + c02 * bz)
    cby = cmy - (c10 * bx + c11 * by + c12 * bz)
    cbz = cmz - (c20 * bx + c21 * by + c22 * bz)
    state[S_MOFF_D_COR] += kd * (_disagreement(state, par, cbx, cby, cbz) - state[S_MOFF_D_COR])
    if state[S_MOFF_D_COR] < par[P_MOFF_EXPLAIN] * state[S_MOFF_D_RAW]:
        return mx - bx, my - by, mz - bz, cbx, cby, cbz
    return mx, my, mz, cmx, cmy, cmz


@njit(cache=True)
def _dcm_of_state(state):
    """C_b^n of the current attitude quaternion, row by row (c00, c01, … c22)."""
    q0 = state[S_Q]
    q1 = state[S_Q + 1]
    q2 = state[S_Q + 2]
    q3 = state[S_Q + 3]
    return (
        1.0 - 2.0 * (q2 * q2 + q3 * q3), 2.0 * (q1 * q2 - q0 * q3), 2.0 * (q1 * q3 + q0 * q2),
        2.0 * (q1 * q2 + q0 * q3), 1.0 - 2.0 * (q1 * q1 + q3 * q3), 2.0 * (q2 * q3 - q0 * q1),
        2.0 * (q1 * q3 - q0 * q2), 2.0 * (q2 * q3 + q0 * q1), 1.0 - 2.0 * (q1 * q1 + q2 * q2),
    )


@njit(cache=True)
def _lowpass_weight(state, slot, dt, tau):
    """1 − exp(−Δt/τ), cached in state[slot : slot + 2] for the last Δt (the sample period rarely changes and
    exp is a good part of a step's cost)."""
    if state[slot] != dt:
        state[slot] = dt
        state[slot + 1] = 1.0 - math.exp(-dt / tau)
    return state[slot + 1]


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
def euler_zyx(q0, q1, q2, q3):
    """ZYX roll, pitch, yaw of a body→NED quaternion, rad."""
    roll = math.atan2(2.0 * (q2 * q3 + q0 * q1), 1.0 - 2.0 * (q1 * q1 + q2 * q2))
    pitch = -math.asin(min(1.0, max(-1.0, 2.0 * (q1 * q3 - q0 * q2))))
    yaw = math.atan2(2.0 * (q1 * q2 + q0 * q3), 1.0 - 2.0 * (q2 * q2 + q3 * q3))
    return roll, pitch, yaw


@njit(cache=True)
def tilt_sigma(cy, sy, pnn, pne, pee):
    """1σ roll and pitch: the NED tilt covariance (P_NN, P_NE, P_EE of δθ) rotated into the heading frame
    (cy, sy: cosine and sine of yaw)."""
    sig_roll = math.sqrt(max(cy * cy * pnn + 2.0 * cy * sy * pne + sy * sy * pee, 0.0))
    sig_pitch = math.sqrt(max(sy * sy * pnn - 2.0 * cy * sy * pne + cy * cy * pee, 0.0))
    return sig_roll, sig_pitch


@njit(cache=True)
def euler_and_tilt_sigma(q0, q1, q2, q3, pnn, pne, pee):
    """ZYX roll, pitch, yaw of a body→NED quaternion, and the 1σ roll and pitch from the NED tilt covariance
    (P_NN, P_NE, P_EE of δθ) rotated into the heading frame."""
    roll, pitch, yaw = euler_zyx(q0, q1, q2, q3)
    sig_roll, sig_pitch = tilt_sigma(math.cos(yaw), math.sin(yaw), pnn, pne, pee)
    return roll, pitch, yaw, sig_roll, sig_pitch


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


@njit(cache=True)
def mekf_step(state, par, t_s, gx, gy, gz, ax, ay, az, mx, my, mz, sample_flags, out):
    """One sample. Returns EstimateFlags bits (| NEEDS_INIT when the caller must initialise first).

    sample_flags: the sample's SampleFlags as an int (invalid or saturated sensors are not used).
    """
    valid = input_validity(sample_flags, gx, gy, gz, ax, ay, az, mx, my, mz)
    dt, flags = step_dt(t_s - state[S_T_LAST], par[P_LARGE_DT], par[P_REINIT_DT])
    if flags & NEEDS_INIT:
        return flags
    state[S_T_LAST] = t_s
    state[S_T_RUN] += dt

    # ------------------------------------------------------------------ rates
    if valid & IN_GYRO_OK:
        state[S_GYR_LAST] = gx
        state[S_GYR_LAST + 1] = gy
        state[S_GYR_LAST + 2] = gz
    else:
        gx = state[S_GYR_LAST]
        gy = state[S_GYR_LAST + 1]
        gz = state[S_GYR_LAST + 2]
    wx = gx - state[S_B]
    wy = gy - state[S_B + 1]
    wz = gz - state[S_B + 2]
    rate = math.sqrt(wx * wx + wy * wy + wz * wz)

    # ------------------------------------------------------------------ strapdown: q ← q ⊗ exp(ω dt)
    qw = state[S_Q]
    qx = state[S_Q + 1]
    qy = state[S_Q + 2]
    qz = state[S_Q + 3]
    if dt > 0.0:
        h = 0.5 * rate * dt   # half the rotation angle of this step
        if h < 0.01:
            # sin h / h and cos h by their series: the rest is below h⁶/720 ≈ 1.4e-15 (exact to double
            # precision); a step turns by 0.01 rad only at 16 rad/s at 819.2 SPS, and libm's sin and cos are
            # a good part of the one-sample cost
            h2 = h * h
            s = 0.5 * dt * (1.0 - h2 / 6.0 * (1.0 - h2 / 20.0))
            cw = 1.0 - 0.5 * h2 * (1.0 - h2 / 12.0)
        else:
            s = math.sin(h) / rate
            cw = math.cos(h)
        ex = wx * s
        ey = wy * s
        ez = wz * s
        nw = qw * cw - qx * ex - qy * ey - qz * ez
        nx = qw * ex + qx * cw + qy * ez - qz * ey
        ny = qw * ey - qx * ez + qy * cw + qz * ex
        nz = qw * ez + qx * ey - qy * ex + qz * cw
        n = math.sqrt(nw * nw + nx * nx + ny * ny + nz * nz)
        qw = nw / n
        qx = nx / n
        qy = ny / n
        qz = nz / n
        state[S_Q] = qw
        state[S_Q + 1] = qx
        state[S_Q + 2] = qy
        state[S_Q + 3] = qz

    # C = C_b^n of the propagated attitude
    c00 = 1.0 - 2.0 * (qy * qy + qz * qz)
    c01 = 2.0 * (qx * qy - qw * qz)
    c02 = 2.0 * (qx * qz + qw * qy)
    c10 = 2.0 * (qx * qy + qw * qz)
    c11 = 1.0 - 2.0 * (qx * qx + qz * qz)
    c12 = 2.0 * (qy * qz - qw * qx)
    c20 = 2.0 * (qx * qz - qw * qy)
    c21 = 2.0 * (qy * qz + qw * qx)
    c22 = 1.0 - 2.0 * (qx * qx + qy * qy)

    # ------------------------------------------------------------------ covariance: Φ P Φᵀ + Q
    # Φ = [[I, −C dt], [0, I]]  (δθ̇ = −C δb − C n_g)
    if dt > 0.0:
        p = S_P
        # M = C dt (3×3), A = P[0:3,0:3], B = P[0:3,3:6], D = P[3:6,3:6]
        m00 = c00 * dt
        m01 = c01 * dt
        m02 = c02 * dt
        m10 = c10 * dt
        m11 = c11 * dt
        m12 = c12 * dt
        m20 = c20 * dt
        m21 = c21 * dt
        m22 = c22 * dt
        # MD = M D
        d00 = state[p + 21]
        d01 = state[p + 22]
        d02 = state[p + 23]
        d10 = state[p + 27]
        d11 = state[p + 28]
        d12 = state[p + 29]
        d20 = state[p + 33]
        d21 = state[p + 34]
        d22 = state[p + 35]
        md00 = m00 * d00 + m01 * d10 + m02 * d20
        md01 = m00 * d01 + m01 * d11 + m02 * d21
        md02 = m00 * d02 + m01 * d12 + m02 * d22
        md10 = m10 * d00 + m11 * d10 + m12 * d20
        md11 = m10 * d01 + m11 * d11 + m12 * d21
        md12 = m10 * d02 + m11 * d12 + m12 * d22
        md20 = m20 * d00 + m21 * d10 + m22 * d20
        md21 = m20 * d01 + m21 * d11 + m22 * d21
        md22 = m20 * d02 + m21 * d12 + m22 * d22
        # B' = B − M D
        b00 = state[p + 3] - md00
        b01 = state[p + 4] - md01
        b02 = state[p + 5] - md02
        b10 = state[p + 9] - md10
        b11 = state[p + 10] - md11
        b12 = state[p + 11] - md12
        b20 = state[p + 15] - md20
        b21 = state[p + 16] - md21
        b22 = state[p + 17] - md22
        # A' = A − M Bᵀ − B Mᵀ + M D Mᵀ = A − M B'ᵀ − B Mᵀ  (using B' = B − M D)
        # with the original B: A' = A − B Mᵀ − M (B − M D)ᵀ = A − B Mᵀ − M B'ᵀ
        ob00 = state[p + 3]
        ob01 = state[p + 4]
        ob02 = state[p + 5]
        ob10 = state[p + 9]
        ob11 = state[p + 10]
        ob12 = state[p + 11]
        ob20 = state[p + 15]
        ob21 = state[p + 16]
        ob22 = state[p + 17]
        # angle random walk, plus the gyro's scale and axis-alignment errors, which turn with the rate
        qa = par[P_GYRO_NOISE] * par[P_GYRO_NOISE] * dt
        qt = qa + (par[P_GYRO_RATE_NOISE] * rate) ** 2 * dt
        qb = par[P_BIAS_WALK] * par[P_BIAS_WALK] * dt
        # rows i of A': A[i][j] − Σk ob[i][k] m[j][k] − Σk m[i][k] b[j][k]
        state[p + 0] += qt - (ob00 * m00 + ob01 * m01 + ob02 * m02) - (m00 * b00 + m01 * b01 + m02 * b02)
        state[p + 1] += -(ob00 * m10 + ob01 * m11 + ob02 * m12) - (m00 * b10 + m01 * b11 + m02 * b12)
        state[p + 2] += -(ob00 * m20 + ob01 * m21 + ob02 * m22) - (m00 * b20 + m01 * b21 + m02 * b22)
        state[p + 7] += qt - (ob10 * m10 + ob11 * m11 + ob12 * m12) - (m10 * b10 + m11 * b11 + m12 * b12)
        state[p + 8] += -(ob10 * m20 + ob11 * m21 + ob12 * m22) - (m10 * b20 + m11 * b21 + m12 * b22)
        state[p + 14] += qa - (ob20 * m20 + ob21 * m21 + ob22 * m22) - (m20 * b20 + m21 * b21 + m22 * b22)
        # A' is symmetric (A and D are, and M B'ᵀ + B Mᵀ = M Bᵀ + B Mᵀ − M D Mᵀ is): mirror the upper triangle,
        # as the scalar updates do, so P stays exactly symmetric without a symmetrising pass
        state[p + 6] = state[p + 1]
        state[p + 12] = state[p + 2]
        state[p + 13] = state[p + 8]
        state[p + 3] = b00
        state[p + 4] = b01
        state[p + 5] = b02
        state[p + 9] = b10
        state[p + 10] = b11
        state[p + 11] = b12
        state[p + 15] = b20
        state[p + 16] = b21
        state[p + 17] = b22
        state[p + 18] = b00
        state[p + 24] = b01
        state[p + 30] = b02
        state[p + 19] = b10
        state[p + 25] = b11
        state[p + 31] = b12
        state[p + 20] = b20
        state[p + 26] = b21
        state[p + 32] = b22
        state[p + 21] += qb
        state[p + 28] += qb
        state[p + 35] += qb

    # ------------------------------------------------------------------ rest detection (VQF-style)
    acc_ok = (valid & IN_ACC_OK) != 0
    at_rest = False
    if dt > 0.0:
        k = _lowpass_weight(state, S_LPW, dt, par[P_REST_TAU])
        for i in range(3):
            g = gx if i == 0 else (gy if i == 1 else gz)
            state[S_GYR_LP + i] += k * (g - state[S_GYR_LP + i])
        if acc_ok:
            state[S_ACC_LP] += k * (ax - state[S_ACC_LP])
            state[S_ACC_LP + 1] += k * (ay - state[S_ACC_LP + 1])
            state[S_ACC_LP + 2] += k * (az - state[S_ACC_LP + 2])
        if (valid & IN_MAG_OK) != 0:
            state[S_MAG_LP] += k * (mx - state[S_MAG_LP])
            state[S_MAG_LP + 1] += k * (my - state[S_MAG_LP + 1])
            state[S_MAG_LP + 2] += k * (mz - state[S_MAG_LP + 2])
        dg = (gx - state[S_GYR_LP]) ** 2 + (gy - state[S_GYR_LP + 1]) ** 2 + (gz - state[S_GYR_LP + 2]) ** 2
        da = (ax - state[S_ACC_LP]) ** 2 + (ay - state[S_ACC_LP + 1]) ** 2 + (az - state[S_ACC_LP + 2]) ** 2
        # the squared deviations are low-passed too and the sensors' own white noise (3 axes × σ² per
        # sample) is subtracted: a noisy gyro (ADIS16405: 0.95 °/s per sample at 819.2 SPS) at rest is
        # still at rest, while a real motion raises the mean deviation at once
        state[S_REST_DG] += k * (dg - state[S_REST_DG])
        state[S_REST_DA] += k * (da - state[S_REST_DA])
        dg = state[S_REST_DG] - 3.0 * par[P_GYRO_NOISE] ** 2 / dt
        da = state[S_REST_DA] - 3.0 * par[P_ACC_NOISE_REST] ** 2
        clip = par[P_BIAS_CLIP]
        lp_small = (abs(state[S_GYR_LP]) < clip) and (abs(state[S_GYR_LP + 1]) < clip) and (
            abs(state[S_GYR_LP + 2]) < clip
        )
        if (
            (valid & IN_GYRO_OK)
            and acc_ok
            and lp_small
            and dg < par[P_REST_GYRO_TH] ** 2
            and da < par[P_REST_ACC_TH] ** 2
            and abs(math.sqrt(state[S_ACC_LP] ** 2 + state[S_ACC_LP + 1] ** 2 + state[S_ACC_LP + 2] ** 2)
                    - state[S_G_REF]) < par[P_REST_ACC_TH]  # at rest the specific force is gravity
        ):
            state[S_REST_T] += dt
        else:
            state[S_REST_T] = 0.0
        at_rest = state[S_REST_T] >= par[P_REST_MIN_T]
    # at rest the body does not turn, so neither may the field it sees: remember it when rest begins
    mag_moved_at_rest = False
    if not at_rest:
        state[S_MAG_REST_SET] = 0.0
    elif valid & IN_MAG_OK:
        if state[S_MAG_REST_SET] == 0.0:
            state[S_MAG_REST] = state[S_MAG_LP]
            state[S_MAG_REST + 1] = state[S_MAG_LP + 1]
            state[S_MAG_REST + 2] = state[S_MAG_LP + 2]
            state[S_MAG_REST_SET] = 1.0
        else:
            dmx = state[S_MAG_LP] - state[S_MAG_REST]
            dmy = state[S_MAG_LP + 1] - state[S_MAG_REST + 1]
            dmz = state[S_MAG_LP + 2] - state[S_MAG_REST + 2]
            mag_moved_at_rest = dmx * dmx + dmy * dmy + dmz * dmz > par[P_MAG_REST_CHANGE] ** 2
    if at_rest:
        flags |= F_AT_REST
        # each gyro sample measures the bias directly, y = b + δb + white noise (R = density²/Δt), so a
        # rest of T seconds averages to σ_b = density/√T. (Feeding the low-passed gyro with a small R, as
        # VQF does, counts the same noise many times: the bias then snaps to whatever the low-pass holds —
        # including the first second of a slow start that rest detection has not yet seen.)
        # The per-sample variance is measured right here: at rest the squared deviation from the low-pass
        # (S_REST_DG, 3 axes) is the sensor's own noise, so the same filter suits a 0.1 °/s and a 1 °/s gyro.
        r = max(state[S_REST_DG] / 3.0, par[P_REST_BIAS_NOISE] ** 2 / dt)
        # sequential scalar updates; the corrections are summed and applied once (each innovation includes
        # the bias corrections of the updates before it)
        a0 = a1 = a2 = a3 = a4 = a5 = 0.0
        for i in range(3):
            gi = gx if i == 0 else (gy if i == 1 else gz)
            bi = a3 if i == 0 else (a4 if i == 1 else a5)
            nu = gi - state[S_B + i] - bi
            d0, d1, d2, d3, d4, d5 = _scalar_update(state, 3 + i, 1.0, nu, r, 0)
            a0 += d0
            a1 += d1
            a2 += d2
            a3 += d3
            a4 += d4
            a5 += d5
        _apply_correction(state, par, a0, a1, a2, a3, a4, a5)

    # ------------------------------------------------------------------ accelerometer: tilt only
    if acc_ok:
        # rotate the specific force into NED with the current estimate
        e00, e01, e02, e10, e11, e12, e20, e21, e22 = _dcm_of_state(state)
        fn = e00 * ax + e01 * ay + e02 * az
        fe = e10 * ax + e11 * ay + e12 * az
        fd = e20 * ax + e21 * ay + e22 * az
        fnorm = math.sqrt(ax * ax + ay * ay + az * az)
        g_ref = state[S_G_REF]
        if at_rest and dt > 0.0:
            # learn |g| as this accelerometer sees it (scale error) while nothing moves (τ = 10 s)
            state[S_G_REF] += _lowpass_weight(state, S_LPW + 6, dt, 10.0) * (fnorm - g_ref)
        tau = par[P_ACC_TAU]
        if tau > 0.0 and dt > 0.0:
            # low-pass in the (estimated) NED frame: linear acceleration averages out, gravity stays (VQF)
            ka = _lowpass_weight(state, S_LPW + 2, dt, tau)
            state[S_ACC_I] += ka * (fn - state[S_ACC_I])
            state[S_ACC_I + 1] += ka * (fe - state[S_ACC_I + 1])
            state[S_ACC_I + 2] += ka * (fd - state[S_ACC_I + 2])
            un = state[S_ACC_I]
            ue = state[S_ACC_I + 1]
            ud = state[S_ACC_I + 2]
        else:
            un = fn
            ue = fe
            ud = fd
        unorm = math.sqrt(un * un + ue * ue + ud * ud)
        dev = abs(unorm - g_ref)  # sustained linear acceleration left after the low-pass
        # unit measured "up" in NED: u = [δθ_E, −δθ_N, −1] (+ noise)
        nu_n = un / unorm if unorm > 0.0 else 0.0
        nu_e = ue / unorm if unorm > 0.0 else 0.0
        # Acceleration-adaptive tilt noise. The low-passed linear acceleration is exactly (v − LP_τ(v)) / τ:
        # the sensor's velocity minus its recent mean, over τ. A hand shaking or moving the sensor about leaves
        # a residual that swings with the motion (degrees of apparent tilt for ±5 m/s² at 1 Hz), not white
        # noise; a real tilt error is a slow drift. So the spread of the innovation around its own running
        # mean measures the residual and is added to the measurement variance (covariance matching:
        # R. K. Mehra, IEEE TAC 15(2), 1970; A. H. Mohamed, K. P. Schwarz, J. Geodesy 73, 1999). A persistent
        # tilt error moves the mean, not the spread, so it is still corrected.
        if par[P_ACC_ADAPT_TAU] > 0.0 and dt > 0.0:
            kw = _lowpass_weight(state, S_LPW + 4, dt, par[P_ACC_ADAPT_TAU])
            state[S_ACC_NU_MEAN], state[S_ACC_NU_VAR] = _running_spread(
                state[S_ACC_NU_MEAN], state[S_ACC_NU_VAR], nu_n, kw)
            state[S_ACC_NU_MEAN + 1], state[S_ACC_NU_VAR + 1] = _running_spread(
                state[S_ACC_NU_MEAN + 1], state[S_ACC_NU_VAR + 1], nu_e, kw)
        r_motion = par[P_ACC_ADAPT_GAIN] * 0.5 * (state[S_ACC_NU_VAR] + state[S_ACC_NU_VAR + 1])
        # reject (a) a sustained push: |f| of the low-pass far from g, (b) a vertical more than the gate angle
        # from the estimate (the covariance of a low-passed, correlated measurement is no honest yardstick;
        # an angle is). Either way the low-pass holds the push: stay off until it has forgotten it (4 τ → 2 %
        # left), unless nothing has been accepted for acc_gate_recover_s (a wrong tilt must recover).
        if (
            dev > par[P_ACC_REJECT]
            or unorm < 0.5 * g_ref
            or nu_n * nu_n + nu_e * nu_e > par[P_ACC_GATE] ** 2
        ):
            state[S_ACC_HOLD_T] = 4.0 * tau
        elif state[S_ACC_HOLD_T] > 0.0:
            state[S_ACC_HOLD_T] -= dt
        accepted = False
        if unorm > 0.5 * g_ref and (state[S_ACC_HOLD_T] <= 0.0 or state[S_ACC_REJ_T] > par[P_ACC_GATE_RECOVER]):
            if at_rest:
                r = (par[P_ACC_NOISE_REST] / g_ref) ** 2 + r_motion
            else:
                # a sustained acceleration a ⟂ g (a turn) tilts the apparent vertical by φ with
                # cos φ = g/|f|: that angle is the size of the error the measurement can carry
                phi = 0.0
                if par[P_ACC_TURN_GAIN] > 0.0:
                    ratio = min(unorm, g_ref) / max(unorm, g_ref)
                    phi = par[P_ACC_TURN_GAIN] * max(math.acos(ratio) - par[P_ACC_TURN_DEAD], 0.0)
                r = (par[P_ACC_NOISE] / g_ref) ** 2 + phi * phi + r_motion
            # never heading; and no bias learning while |f| is off g (a push would be read as bias)
            mask = M_HEADING if abs(fnorm - g_ref) < par[P_REST_ACC_TH] else (M_HEADING | M_BIAS)
            a0, a1, a2, a3, a4, a5 = _scalar_update(state, 1, 1.0, nu_n, r, mask)
            # second component: innovation re-evaluated after the first correction (sequential update); the
            # two corrections are applied together
            nu_e2 = nu_e + a0
            d0, d1, d2, d3, d4, d5 = _scalar_update(state, 0, -1.0, nu_e2, r, mask)
            _apply_correction(state, par, a0 + d0, a1 + d1, a2 + d2, a3 + d3, a4 + d4, a5 + d5)
            accepted = True
        if accepted:
            state[S_ACC_REJ_T] = 0.0
        else:
            flags |= F_ACCEL_REJECTED
            state[S_ACC_REJ_T] += dt

    # ------------------------------------------------------------------ body-fixed field offset (attached magnet)
    offset_on = (valid & IN_MAG_OK) and par[P_MOFF_TAU] > 0.0 and par[P_MAG_ENABLED] > 0.0
    mn = me = md = 0.0
    if offset_on:
        mx, my, mz, mn, me, md = _field_offset(state, par, dt, rate, mx, my, mz)

    # ------------------------------------------------------------------ magnetometer: heading only
    mag_used = False
    if (valid & IN_MAG_OK) and par[P_MAG_ENABLED] > 0.0:
        if not offset_on:
            mn, me, md = mag.rotate_to_ned(state[S_Q], state[S_Q + 1], state[S_Q + 2], state[S_Q + 3], mx, my, mz)
        mnorm = math.sqrt(mx * mx + my * my + mz * mz)
        res, alpha, r = mag.heading_measurement(state, S_MAG, par, P_MAG, dt, rate, at_rest, mag_moved_at_rest,
                                                mn, me, md, mnorm, 0.0, state[S_P + 2 * 6 + 2])
        if res == mag.MAG_USE:
            d0, d1, d2, d3, d4, d5 = _scalar_update(state, 2, -1.0, alpha, r, M_TILT)
            _apply_correction(state, par, d0, d1, d2, d3, d4, d5)
            mag_used = True
        elif res == mag.MAG_REJECTED:
            flags |= F_MAG_REJECTED
    if mag.heading_bookkeeping(state, S_MAG, par, P_MAG, dt, mag_used):
        flags |= F_MAG_UNAVAILABLE

    # ------------------------------------------------------------------ outputs
    q0 = state[S_Q]
    q1 = state[S_Q + 1]
    q2 = state[S_Q + 2]
    q3 = state[S_Q + 3]
    if q0 < 0.0:
        q0 = -q0
        q1 = -q1
        q2 = -q2
        q3 = -q3
    out[O_Q] = q0
    out[O_Q + 1] = q1
    out[O_Q + 2] = q2
    out[O_Q + 3] = q3
    out[O_RATE] = gx - state[S_B]
    out[O_RATE + 1] = gy - state[S_B + 1]
    out[O_RATE + 2] = gz - state[S_B + 2]
    # 1σ roll/pitch: NED tilt covariance rotated into the heading frame (cos, sin of yaw = C00, C10 over
    # their norm: no atan2, cos, sin on the hot path); yaw: δθ_D
    cy = 1.0 - 2.0 * (q2 * q2 + q3 * q3)
    sy = 2.0 * (q1 * q2 + q0 * q3)
    hy = math.sqrt(cy * cy + sy * sy)
    if hy > 1e-12:
        cy /= hy
        sy /= hy
    else:
        cy = 1.0
        sy = 0.0
    out[O_SIGMA], out[O_SIGMA + 1] = tilt_sigma(cy, sy, state[S_P + 0], state[S_P + 1], state[S_P + 7])
    out[O_SIGMA + 2] = math.sqrt(max(state[S_P + 14], 0.0))
    out[O_BIAS] = state[S_B]
    out[O_BIAS + 1] = state[S_B + 1]
    out[O_BIAS + 2] = state[S_B + 2]
    if initialising(state[S_T_RUN], out[O_SIGMA], out[O_SIGMA + 1], out[O_SIGMA + 2], par[P_INIT_TIME],
                    par[P_CONV_TILT], par[P_MAG_ENABLED] > 0.0, par[P_CONV_YAW]):
        flags |= F_INITIALISING
    return flags


# the one-sample path's buffer: [state | par | out] in one array, so a call unboxes one array, not three
B_PAR = S_SIZE
B_OUT = S_SIZE + P_SIZE
B_SIZE = B_OUT + O_SIZE


@njit(cache=True)
def mekf_step_full(buf, t_s, gyro, acc, mag, sample_flags):
    """`mekf_step` on the buffer `buf` (layout B_*) for one sample's (3,) vectors, plus the ZYX Euler angles in
    its out[O_EULER:] (the one-sample path; batch runs skip them). Returns BAD_SHAPE if a vector does not have
    3 elements (nothing changed)."""
    if gyro.shape[0] != 3 or acc.shape[0] != 3 or mag.shape[0] != 3:
        return BAD_SHAPE
    b = borrowed(buf)   # the caller holds buf for the call: no reference counting in the step
    state = b[:B_PAR]
    par = b[B_PAR:B_OUT]
    out = b[B_OUT:]
    f = mekf_step(state, par, t_s, gyro[0], gyro[1], gyro[2], acc[0], acc[1], acc[2], mag[0], mag[1], mag[2],
                  sample_flags, out)
    if not f & NEEDS_INIT:
        roll, pitch, yaw = euler_zyx(out[O_Q], out[O_Q + 1], out[O_Q + 2], out[O_Q + 3])
        out[O_EULER] = roll
        out[O_EULER + 1] = pitch
        out[O_EULER + 2] = yaw
    return f


@njit(cache=True)
def mekf_run(state, par, t_s, gyro, acc, mag, sample_flags, start, q_out, flags_out):
    """Run `mekf_step` over samples start… Returns the index of the first sample that needs
    (re-)initialisation, or len(t_s) when all were processed. sample_flags (N,) int64 SampleFlags;
    q_out (N, 4), flags_out (N,)."""
    out = np.empty(O_SIZE)
    # views without reference counting (`borrowed`): state and par are the caller's, held for the whole call;
    # out is read below after every step, so it lives through the loop
    st = borrowed(state)
    pa = borrowed(par)
    n = t_s.shape[0]
    for i in range(start, n):
        f = mekf_step(
            st, pa, t_s[i],
            gyro[i, 0], gyro[i, 1], gyro[i, 2],
            acc[i, 0], acc[i, 1], acc[i, 2],
            mag[i, 0], mag[i, 1], mag[i, 2],
            sample_flags[i], borrowed(out),
        )
        if f & NEEDS_INIT:
            return i
        for j in range(4):
            q_out[i, j] = out[O_Q + j]
        flags_out[i] = f
    return n


_SIGNATURE = "int64(float64[::1], float64, float64[:], float64[:], float64[:], int64)"


_FAST_STEP = []   # the entry point, once looked up (each Mekf() asks for it; resolving it costs ≈ 60 µs)


def fast_step():
    """`mekf_step_full` as a directly callable compiled entry point for one-sample calls (looked up once per
    process).

    Numba's dispatcher resolves argument types on every call (≈5 µs, ten times the filter's own
    arithmetic); the entry point of the one compiled signature skips that. Arguments must then have exactly
    that signature, which the entry point does not check (an int64 array would be read as float64): the
    buffer is the caller's own, and the caller passes only float64 vectors (dtype checked; their length is
    checked here). Falls back to the dispatcher if this numba version does not expose entry points (same
    code, slower call)."""
    if not _FAST_STEP:
        _FAST_STEP.append(_entry_point())
    return _FAST_STEP[0]


def _entry_point():
    try:
        mekf_step_full.compile(_SIGNATURE)
        for sig, cres in mekf_step_full.overloads.items():
            if len(sig) == 6 and str(sig[5]) == "int64" and str(sig[1]) == "float64":
                return cres.entry_point
    except Exception:  # pragma: no cover - numba internals moved
        pass
    return mekf_step_full  # pragma: no cover
