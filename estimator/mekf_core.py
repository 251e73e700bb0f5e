"""The MEKF's per-sample step, compiled with numba (the one implementation of the algorithm).

`mekf.py` owns the parameters, initialisation (weighted Wahba) and the Estimator interface; this module is
the hot path. The filter's state is one MEKF_STATE_DTYPE record, its parameters one MEKF_PARAMS_DTYPE record
and a step's outputs one MEKF_OUT_DTYPE record (numpy structured types that numba compiles to loads and
stores at fixed offsets), so a step allocates nothing and one numba call serves a sample. `mekf_step` runs the
stages in order:

  `_propagate_attitude`, `_propagate_covariance`  strapdown q ← q ⊗ exp(ω Δt); P ← Φ P Φᵀ + Q in 3×3 blocks
                                                 (`_bias_block_product` M D, `_propagate_attitude_block` A')
  `_detect_rest`, `_learn_bias_at_rest`          rest detection (`_rest_lowpasses`, `_steady`,
                                                 `_field_moved_at_rest`); at rest each gyro sample measures the bias
  `_tilt_update`                                 the accelerometer's vertical corrects tilt only:
                                                 `_vertical_lowpass` (f in NED, low-passed), `_motion_noise_rad2`,
                                                 `_vertical_accepted` (the gate), `_vertical_noise_rad2`,
                                                 `_correct_tilt` (two constrained scalar updates), or at rest
                                                 while f leans without the gyro turning (unturned_lean.py: a
                                                 speed change) `_correct_tilt_across` (across the lean only)
  `_field_offset`                                a body-fixed field offset learned and removed (attached magnet):
                                                 `_turned_since_snapshot`, `_refit_offset` (least squares),
                                                 `_take_snapshot`, `_offset_explained_field` (the field to use)
  `_heading_update`                              the magnetometer corrects heading only (mag_heading.py's check:
                                                 `_track_field` against the reference, `_heading_innovation`)
  `_fill_outputs`                                quaternion, rate, 1σ, bias (the one-sample path publishes them)
  `_fill_estimate`                               quaternion only (the batch returns nothing else)

`mekf_run` loops the same `mekf_step` over arrays for replay and benchmarks; it fills only what it returns.
The sub-stages of a stage are compiled into it (numba `inline="always"`), so splitting a stage adds no call.

Error state (6): δθ, the attitude error in the NED frame (C_true = (I + [δθ×]) C_est), and δb, the gyro bias
error (b_true = b_est + δb). Tilt is δθ_N, δθ_E; heading is δθ_D. The accelerometer observes only
δθ_N, δθ_E and the magnetometer only δθ_D (their measurement rows), and their gains on the other attitude
components are forced to zero (constrained_update.py, Joseph form), so neither can move what it does not
observe through the covariance's cross terms: a magnetic disturbance cannot move the horizon, linear
acceleration cannot move the heading.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, typeof, types
from numba.core import cgutils
from numba.extending import intrinsic

from . import mag_heading as mag
from .accel_axes_tilt import accel_axes_tilt_variance_in_force_rad2
from .constrained_update import pair_update_6, scalar_update_6
from .kernel_entry import entry_point
from .kernel_flags import (
    BAD_SHAPE,
    F_ACCEL_REJECTED,
    F_AT_REST,
    F_INITIALISING,
    F_LARGE_DT,
    F_MAG_REJECTED,
    F_MAG_UNAVAILABLE,
    F_REINITIALISED,
    IN_ACC_OK,
    IN_GYRO_OK,
    IN_MAG_OK,
    NEEDS_INIT,
    initialising,
    input_validity,
    step_dt,
)
from .kernel_rotations import dcm, euler_zyx, normalised, quat_mul, rotate_to_ned, tilt_sigma
from .turn_lean import (
    ACCEL_PUSH_MEMORY_S,
    TURN_LEAN_DTYPE,
    RestLearning,
    bound_pushes,
    levelling_gain,
    lowpass_rate_down,
    prior_share,
    tilt_pushes_rad,
    track_accel_push_kept,
    track_bias_learning,
    track_heading_push,
    track_lean_bias_drift,
    track_tilt_push,
    track_turn_speed,
    turn_speed_m_s,
)
from .unturned_lean import UNTURNED_LEAN_DTYPE, add_correction, leans_unturned, lowpass_f

__all__ = [
    "MEKF_STATE_DTYPE", "MEKF_PARAMS_DTYPE", "MEKF_OUT_DTYPE", "MEKF_BUFFER_DTYPE", "mekf_step", "mekf_step_full",
    "mekf_run", "fast_step", "fill_euler", "fast_fill_euler", "fill_outputs_after_init", "fast_fill_after_init", "input_validity", "BAD_SHAPE", "NEEDS_INIT",
    "IN_ACC_OK", "IN_GYRO_OK", "IN_MAG_OK",
    "F_INITIALISING", "F_MAG_REJECTED", "F_ACCEL_REJECTED", "F_AT_REST", "F_MAG_UNAVAILABLE", "F_LARGE_DT",
    "F_REINITIALISED", "E_TILT_N", "E_TILT_E", "E_HEADING", "E_BIAS",
]

# ----------------------------------------------------------------------------------- state
# 1 − exp(−Δt/τ) of a low-pass, cached for the last Δt (the sample period rarely changes; exp is a good part
# of a step's cost)
LOWPASS_WEIGHT_DTYPE = np.dtype([("dt_s", np.float64), ("k", np.float64)])

FIELD_OFFSET_DTYPE = np.dtype([           # the body-fixed field offset estimate (`_field_offset`)
    ("b_ut", np.float64, (3,)),           # the offset (a magnet attached after calibration), body frame
    ("P_ut2", np.float64, (3, 3)),        # its covariance
    ("cm_ut", np.float64, (3,)),          # C·m (field in the estimated NED frame) at the previous snapshot
    ("c", np.float64, (3, 3)),            # C_b^n at the previous snapshot
    ("since_snapshot_s", np.float64),     # time since the previous snapshot
    ("snapshot_set", np.bool_),           # the previous snapshot is valid
    ("nis", np.float64),                  # running mean of the fit's normalised squared innovation
    ("disagree_raw", np.float64),         # running disagreement of the raw field with the reference
    ("disagree_corrected", np.float64),   # ... of the offset-corrected field
    ("dip_cached_rad", np.float64),       # the reference dip whose sine and cosine are cached (`_disagreement`)
    ("dip_sin", np.float64),
    ("dip_cos", np.float64),              # 0: nothing cached
    ("ready", np.bool_),                  # known well enough, significant and consistent: subtracted
])

MEKF_STATE_DTYPE = np.dtype([
    ("q", np.float64, (4,)),                  # attitude quaternion body→NED, scalar first
    ("gyro_bias_rad_s", np.float64, (3,)),
    ("P", np.float64, (6, 6)),                # error covariance [δθ (rad), δb (rad/s)]
    ("t_last_s", np.float64),                 # time of the previous sample
    ("t_run_s", np.float64),                  # time since initialisation
    ("gyro_last_rad_s", np.float64, (3,)),    # last valid gyro sample
    # rest detection
    ("gyro_lp_rad_s", np.float64, (3,)),      # low-passed gyro
    ("acc_lp_m_s2", np.float64, (3,)),        # low-passed specific force
    ("mag_lp_ut", np.float64, (3,)),          # low-passed body-frame field
    ("rest_dev_gyro", np.float64),            # low-passed squared gyro deviation from its low-pass, (rad/s)²
    ("rest_dev_acc", np.float64),             # ... specific force, (m/s²)²
    ("rest_t_s", np.float64),                 # time the rest conditions have held
    ("mag_rest_ut", np.float64, (3,)),        # body-frame field when the current rest began
    ("mag_rest_set", np.bool_),               # mag_rest_ut holds this rest's field
    # tilt
    ("g_ref_m_s2", np.float64),               # gravity magnitude learned at rest
    ("acc_ned_lp_m_s2", np.float64, (3,)),    # specific force low-passed in the estimated NED frame
    ("acc_since_accept_s", np.float64),       # time since the last accepted tilt update
    ("acc_hold_s", np.float64),               # tilt updates stay off this much longer after a sustained push
    ("acc_nu_mean_rad", np.float64, (2,)),    # running mean of the tilt innovation (north, east)
    ("acc_nu_var_rad2", np.float64, (2,)),    # running mean square deviation of the innovation from it
    # heading
    ("mag", mag.MAG_HEADING_STATE_DTYPE),     # the magnetometer heading check
    ("offset", FIELD_OFFSET_DTYPE),
    ("unmodelled", TURN_LEAN_DTYPE),          # attitude errors the covariance does not carry (turn_lean.py)
    ("unturned", UNTURNED_LEAN_DTYPE),        # the lean of f the gyro did not turn: no rest (unturned_lean.py)
    # cached low-pass weights
    ("lp_rest", LOWPASS_WEIGHT_DTYPE),
    ("lp_acc_ned", LOWPASS_WEIGHT_DTYPE),
    ("lp_spread", LOWPASS_WEIGHT_DTYPE),
    ("lp_g_ref", LOWPASS_WEIGHT_DTYPE),
    ("lp_disagree", LOWPASS_WEIGHT_DTYPE),
    ("push_keep", LOWPASS_WEIGHT_DTYPE),      # its k: exp(−Δt/ACCEL_PUSH_MEMORY_S) (`_push_keep`)
])

# ----------------------------------------------------------------------------------- parameters
# MekfParams' fields of the same names (mekf.py documents each), as the kernel reads them
MEKF_PARAMS_DTYPE = np.dtype([
    ("gyro_noise_rad_s_sqrt_hz", np.float64),
    ("gyro_bias_walk_rad_s_sqrt_s", np.float64),
    ("gyro_rate_noise_sqrt_s", np.float64),
    ("gyro_bias_clip_rad_s", np.float64),
    ("acc_noise_m_s2", np.float64),
    ("acc_noise_rest_m_s2", np.float64),
    ("acc_turn_noise_gain", np.float64),
    ("acc_turn_dead_zone_rad", np.float64),
    ("turn_speed_m_s", np.float64),
    ("acc_reject_m_s2", np.float64),
    ("acc_gate_rad", np.float64),
    ("acc_gate_recover_s", np.float64),
    ("acc_lowpass_tau_s", np.float64),
    ("acc_adaptive_gain", np.float64),
    ("acc_adaptive_tau_s", np.float64),
    ("mag_enabled", np.bool_),
    ("mag", mag.MAG_HEADING_PARAMS_DTYPE),
    ("mag_rest_change_ut", np.float64),
    ("mag_offset_tau_s", np.float64),
    ("mag_offset_min_cos", np.float64),       # cos(mag_offset_min_angle_rad)
    ("mag_offset_use_sigma_ut", np.float64),
    ("mag_offset_lag_s", np.float64),
    ("mag_offset_agree_tau_s", np.float64),
    ("mag_offset_explain_ratio", np.float64),
    ("rest_gyro_th_rad_s", np.float64),
    ("rest_acc_th_m_s2", np.float64),
    ("rest_min_time_s", np.float64),
    ("rest_filter_tau_s", np.float64),
    ("rest_gyro_noise_floor_rad_s_sqrt_hz", np.float64),
    ("init_min_time_s", np.float64),
    ("converged_tilt_rad", np.float64),
    ("converged_yaw_rad", np.float64),
    ("heading_calibration_var_rad2", np.float64),   # calibration_heading.py: the calibration's heading error, 1σ²
    ("accel_bias_sigma_m_s2", np.float64),
    ("accel_axes_tilt_sigma_rad", np.float64),
    ("large_dt_s", np.float64),
    ("reinit_dt_s", np.float64),
])

# ----------------------------------------------------------------------------------- outputs (per step)
MEKF_OUT_DTYPE = np.dtype([
    ("q", np.float64, (4,)),                 # body→NED, scalar ≥ 0
    ("rate_rad_s", np.float64, (3,)),        # bias-corrected rate
    ("sigma_rpy_rad", np.float64, (3,)),     # roll, pitch, yaw 1σ
    ("gyro_bias_rad_s", np.float64, (3,)),
    ("euler_rad", np.float64, (3,)),         # roll, pitch, yaw (ZYX, yaw magnetic in [−π, π]); one-sample path
])

# the one-sample path's buffer: state, parameters and outputs in one record, so a call unboxes one array
MEKF_BUFFER_DTYPE = np.dtype([("state", MEKF_STATE_DTYPE), ("par", MEKF_PARAMS_DTYPE), ("out", MEKF_OUT_DTYPE)])

# error-state components (module docstring): tilt δθ_N, δθ_E; heading δθ_D; gyro bias δb (3)
E_TILT_N, E_TILT_E, E_HEADING, E_BIAS = 0, 1, 2, 3
# error-state component masks for scalar_update_6's zero_mask (bit i = component i)
M_TILT = (1 << E_TILT_N) | (1 << E_TILT_E)
M_HEADING = 1 << E_HEADING
M_BIAS = 0b111 << E_BIAS


@intrinsic
def borrowed(typingctx, arr):
    """A view of the array `arr` (same data, shape, strides) that holds no reference to its owner (numba's
    meminfo is null), for compiled code only.

    Numba counts references to an array with atomic instructions (`NRT_incref`/`NRT_decref`: a `lock incq`
    each) when a compiled function that receives it starts and returns; its reference-count pruning pass removes
    them only in functions with simple control flow. Valid only while the owner is alive: the entry points
    borrow their own arguments (which the caller holds for the whole call) and use the view only inside that
    call."""

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


# ----------------------------------------------------------------------------------- small helpers
@njit(cache=True)
def _lowpass_weight(w, dt, tau):
    """1 − exp(−Δt/τ), cached in the LOWPASS_WEIGHT_DTYPE record `w` for the last Δt."""
    if w.dt_s != dt:
        w.dt_s = dt
        w.k = 1.0 - math.exp(-dt / tau)
    return w.k


@njit(cache=True, inline="always")
def _push_keep(w, dt):
    """exp(−Δt/ACCEL_PUSH_MEMORY_S), the speed change's sum's forgetting (turn_lean.track_accel_push), cached in
    the LOWPASS_WEIGHT_DTYPE record `w` (its k) for the last Δt: the same number as computing it each step.
    An unset record (k = 0) is computed: the exp is not 0 for any step the filter takes, and were it 0 it would
    be computed again to the same 0."""
    if w.dt_s != dt or w.k == 0.0:
        w.dt_s = dt
        w.k = math.exp(-dt / ACCEL_PUSH_MEMORY_S)
    return w.k


@njit(cache=True)
def _running_spread(mean, var, x, k):
    """Running mean of x and running mean square deviation of x from it, both low-passed with weight
    k = 1 − exp(−Δt/τ). Returns (mean, var)."""
    mean += k * (x - mean)
    d = x - mean
    var += k * (d * d - var)
    return mean, var


@njit(cache=True)
def _apply_correction(st, par, dx0, dx1, dx2, dx3, dx4, dx5):
    """q ← exp(δθ) ⊗ q (NED-frame error, first-order exponential, normalised), b ← b + δb (clipped); rotates
    the NED low-pass with the frame."""
    # |h ⊗ q| = |h| |q|: normalising the product normalises the first-order exponential h = [1, δθ/2] as well
    q = st.q
    q[0], q[1], q[2], q[3] = normalised(*quat_mul(1.0, 0.5 * dx0, 0.5 * dx1, 0.5 * dx2, q[0], q[1], q[2], q[3]))
    clip = par.gyro_bias_clip_rad_s
    b = st.gyro_bias_rad_s
    b[0] = min(max(b[0] + dx3, -clip), clip)
    b[1] = min(max(b[1] + dx4, -clip), clip)
    b[2] = min(max(b[2] + dx5, -clip), clip)
    add_correction(st.unturned, dx0, dx1, dx2)
    # the NED-frame low-passed specific force lives in the estimated NED frame: keep it there
    f = st.acc_ned_lp_m_s2
    ax = f[0]
    ay = f[1]
    az = f[2]
    f[0] = ax + dx1 * az - dx2 * ay
    f[1] = ay + dx2 * ax - dx0 * az
    f[2] = az + dx0 * ay - dx1 * ax


# ----------------------------------------------------------------------------------- propagation
@njit(cache=True)
def _propagate_attitude(q, dt, wx, wy, wz, rate):
    """Strapdown: q ← q ⊗ [cos h, ω̂ sin h], h = |ω| Δt / 2, for the bias-corrected rate ω (|ω| = rate),
    normalised."""
    qw = q[0]
    qx = q[1]
    qy = q[2]
    qz = q[3]
    h = 0.5 * rate * dt   # half the rotation angle of this step
    if h < 0.01:
        # sin h / h and cos h by their series: the rest is below h⁶/720 ≈ 1.4e-15 (exact to double
        # precision), and this avoids libm's sin and cos on the hot path
        h2 = h * h
        s = 0.5 * dt * (1.0 - h2 / 6.0 * (1.0 - h2 / 20.0))
        cw = 1.0 - 0.5 * h2 * (1.0 - h2 / 12.0)
    else:
        s = math.sin(h) / rate
        cw = math.cos(h)
    q[0], q[1], q[2], q[3] = normalised(*quat_mul(qw, qx, qy, qz, cw, wx * s, wy * s, wz * s))


@njit(cache=True)
def _tilt_process_noise_rad2(par, rate_rad_s, span_s):
    """The tilt error variance the gyro adds over span_s while turning at rate_rad_s: its angle random walk plus
    its rate-proportional scale/alignment errors, (σ_g² + (σ_s·|ω|)²)·Δt. The one definition of the tilt process
    noise: the covariance propagation adds it per step, and the published σ adds it over the low-passed vertical's
    age (`_fill_outputs`). The heading gets the random walk only (qa in `_propagate_covariance`)."""
    arw_rad2 = par.gyro_noise_rad_s_sqrt_hz * par.gyro_noise_rad_s_sqrt_hz * span_s
    return arw_rad2 + (par.gyro_rate_noise_sqrt_s * rate_rad_s) ** 2 * span_s


@njit(cache=True, inline="always")
def _bias_block_product(P, m):
    """M D for M = C Δt (the 9-tuple `m`, row-major) and D = P[δb, δb]; returns M D as a row-major 9-tuple."""
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = m
    d00 = P[3, 3]
    d01 = P[3, 4]
    d02 = P[3, 5]
    d10 = P[4, 3]
    d11 = P[4, 4]
    d12 = P[4, 5]
    d20 = P[5, 3]
    d21 = P[5, 4]
    d22 = P[5, 5]
    return (m00 * d00 + m01 * d10 + m02 * d20, m00 * d01 + m01 * d11 + m02 * d21, m00 * d02 + m01 * d12 + m02 * d22,
            m10 * d00 + m11 * d10 + m12 * d20, m10 * d01 + m11 * d11 + m12 * d21, m10 * d02 + m11 * d12 + m12 * d22,
            m20 * d00 + m21 * d10 + m22 * d20, m20 * d01 + m21 * d11 + m22 * d21, m20 * d02 + m21 * d12 + m22 * d22)


@njit(cache=True, inline="always")
def _cross_block(P):
    """B = P[δθ, δb] as a row-major 9-tuple."""
    return (P[0, 3], P[0, 4], P[0, 5], P[1, 3], P[1, 4], P[1, 5], P[2, 3], P[2, 4], P[2, 5])


@njit(cache=True, inline="always")
def _propagate_attitude_block(P, m, ob, b, qt, qa):
    """A' = A − B Mᵀ − M B'ᵀ + Q_θ (B = `ob` before, B' = `b` after; row-major 9-tuples), tilt noise `qt` on
    δθ_N, δθ_E, heading noise `qa` on δθ_D: the upper triangle, mirrored. A' is symmetric (A and D are, and
    M B'ᵀ + B Mᵀ = M Bᵀ + B Mᵀ − M D Mᵀ is): mirroring keeps P exactly symmetric, as the scalar updates do,
    without a symmetrising pass."""
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = m
    ob00, ob01, ob02, ob10, ob11, ob12, ob20, ob21, ob22 = ob
    b00, b01, b02, b10, b11, b12, b20, b21, b22 = b
    # row i, column j: A[i][j] − Σk ob[i][k] m[j][k] − Σk m[i][k] b[j][k]
    P[0, 0] += qt - (ob00 * m00 + ob01 * m01 + ob02 * m02) - (m00 * b00 + m01 * b01 + m02 * b02)
    P[0, 1] += -(ob00 * m10 + ob01 * m11 + ob02 * m12) - (m00 * b10 + m01 * b11 + m02 * b12)
    P[0, 2] += -(ob00 * m20 + ob01 * m21 + ob02 * m22) - (m00 * b20 + m01 * b21 + m02 * b22)
    P[1, 1] += qt - (ob10 * m10 + ob11 * m11 + ob12 * m12) - (m10 * b10 + m11 * b11 + m12 * b12)
    P[1, 2] += -(ob10 * m20 + ob11 * m21 + ob12 * m22) - (m10 * b20 + m11 * b21 + m12 * b22)
    P[2, 2] += qa - (ob20 * m20 + ob21 * m21 + ob22 * m22) - (m20 * b20 + m21 * b21 + m22 * b22)
    P[1, 0] = P[0, 1]
    P[2, 0] = P[0, 2]
    P[2, 1] = P[1, 2]


@njit(cache=True)
def _propagate_covariance(P, par, dt, rate, c):
    """P ← Φ P Φᵀ + Q over Δt with Φ = [[I, −C Δt], [0, I]] (δθ̇ = −C δb − C n_g), C = C_b^n (`c`: `dcm`'s
    9-tuple), written out in 3×3 blocks: A = P[δθ, δθ], B = P[δθ, δb], D = P[δb, δb], M = C Δt:
    B' = B − M D,  A' = A − B Mᵀ − M B'ᵀ (= A − M Bᵀ − B Mᵀ + M D Mᵀ),  D' = D.
    Q: angle random walk and the gyro's rate-proportional scale/alignment errors on δθ (tilt; heading the
    random walk only), bias random walk on δb."""
    c00, c01, c02, c10, c11, c12, c20, c21, c22 = c
    m = (c00 * dt, c01 * dt, c02 * dt, c10 * dt, c11 * dt, c12 * dt, c20 * dt, c21 * dt, c22 * dt)
    md00, md01, md02, md10, md11, md12, md20, md21, md22 = _bias_block_product(P, m)
    ob = _cross_block(P)
    ob00, ob01, ob02, ob10, ob11, ob12, ob20, ob21, ob22 = ob
    b00 = ob00 - md00
    b01 = ob01 - md01
    b02 = ob02 - md02
    b10 = ob10 - md10
    b11 = ob11 - md11
    b12 = ob12 - md12
    b20 = ob20 - md20
    b21 = ob21 - md21
    b22 = ob22 - md22
    qa = par.gyro_noise_rad_s_sqrt_hz * par.gyro_noise_rad_s_sqrt_hz * dt
    qt = _tilt_process_noise_rad2(par, rate, dt)
    _propagate_attitude_block(P, m, ob, (b00, b01, b02, b10, b11, b12, b20, b21, b22), qt, qa)
    P[0, 3] = P[3, 0] = b00
    P[0, 4] = P[4, 0] = b01
    P[0, 5] = P[5, 0] = b02
    P[1, 3] = P[3, 1] = b10
    P[1, 4] = P[4, 1] = b11
    P[1, 5] = P[5, 1] = b12
    P[2, 3] = P[3, 2] = b20
    P[2, 4] = P[4, 2] = b21
    P[2, 5] = P[5, 2] = b22
    qb = par.gyro_bias_walk_rad_s_sqrt_s * par.gyro_bias_walk_rad_s_sqrt_s * dt
    P[3, 3] += qb
    P[4, 4] += qb
    P[5, 5] += qb


# ----------------------------------------------------------------------------------- rest
@njit(cache=True, inline="always")
def _rest_lowpasses(st, k, valid, gx, gy, gz, ax, ay, az, mx, my, mz):
    """The gyro, specific force and body-frame field low-passed with weight k (each sensor while valid)."""
    glp = st.gyro_lp_rad_s
    alp = st.acc_lp_m_s2
    mlp = st.mag_lp_ut
    for i in range(3):
        g = gx if i == 0 else (gy if i == 1 else gz)
        glp[i] += k * (g - glp[i])
    if valid & IN_ACC_OK:
        alp[0] += k * (ax - alp[0])
        alp[1] += k * (ay - alp[1])
        alp[2] += k * (az - alp[2])
    if (valid & IN_MAG_OK) != 0:
        mlp[0] += k * (mx - mlp[0])
        mlp[1] += k * (my - mlp[1])
        mlp[2] += k * (mz - mlp[2])


@njit(cache=True, inline="always")
def _steady(st, par, dt, k, valid, gx, gy, gz, ax, ay, az):
    """Gyro and specific force close to their low-passes (`_rest_lowpasses`), the low-passed gyro within the bias
    clip and the specific force's magnitude that of gravity. The squared deviations are low-passed too (weight
    k) and the sensors' own white noise (3 axes × σ² per sample) is subtracted: a noisy gyro at rest is still at
    rest, while a real motion raises the mean deviation at once."""
    glp = st.gyro_lp_rad_s
    alp = st.acc_lp_m_s2
    dg = (gx - glp[0]) ** 2 + (gy - glp[1]) ** 2 + (gz - glp[2]) ** 2
    da = (ax - alp[0]) ** 2 + (ay - alp[1]) ** 2 + (az - alp[2]) ** 2
    st.rest_dev_gyro += k * (dg - st.rest_dev_gyro)
    st.rest_dev_acc += k * (da - st.rest_dev_acc)
    dg = st.rest_dev_gyro - 3.0 * par.gyro_noise_rad_s_sqrt_hz ** 2 / dt
    da = st.rest_dev_acc - 3.0 * par.acc_noise_rest_m_s2 ** 2
    clip = par.gyro_bias_clip_rad_s
    lp_small = (abs(glp[0]) < clip) and (abs(glp[1]) < clip) and (abs(glp[2]) < clip)
    return bool(
        (valid & IN_GYRO_OK)
        and (valid & IN_ACC_OK) != 0
        and lp_small
        and dg < par.rest_gyro_th_rad_s ** 2
        and da < par.rest_acc_th_m_s2 ** 2
        and abs(math.sqrt(alp[0] ** 2 + alp[1] ** 2 + alp[2] ** 2)
                - st.g_ref_m_s2) < par.rest_acc_th_m_s2  # at rest the specific force is gravity
    )


@njit(cache=True, inline="always")
def _field_moved_at_rest(st, par, valid, at_rest):
    """At rest the body does not turn, so neither may the field it sees: the low-passed field is remembered when
    rest begins; True when it has since moved by more than mag_rest_change_ut (something magnetic moved)."""
    if not at_rest:
        st.mag_rest_set = False
        return False
    if not valid & IN_MAG_OK:
        return False
    mlp = st.mag_lp_ut
    mrest = st.mag_rest_ut
    if not st.mag_rest_set:
        mrest[0] = mlp[0]
        mrest[1] = mlp[1]
        mrest[2] = mlp[2]
        st.mag_rest_set = True
        return False
    dmx = mlp[0] - mrest[0]
    dmy = mlp[1] - mrest[1]
    dmz = mlp[2] - mrest[2]
    return dmx * dmx + dmy * dmy + dmz * dmz > par.mag_rest_change_ut ** 2


@njit(cache=True)
def _detect_rest(st, par, dt, valid, gx, gy, gz, ax, ay, az, mx, my, mz):
    """VQF-style rest detection (D. Laidig, T. Seel, Information Fusion 91, 2023, §IV-C): gyro and specific
    force stay close to their low-passes, with the sensors' own white noise subtracted (`_steady`), for
    rest_min_time_s. Returns (at rest, the body-frame field moved since the rest began: something magnetic
    moved nearby, `_field_moved_at_rest`)."""
    at_rest = False
    if dt > 0.0:
        k = _lowpass_weight(st.lp_rest, dt, par.rest_filter_tau_s)
        _rest_lowpasses(st, k, valid, gx, gy, gz, ax, ay, az, mx, my, mz)
        if _steady(st, par, dt, k, valid, gx, gy, gz, ax, ay, az):
            st.rest_t_s += dt
        else:
            st.rest_t_s = 0.0
        at_rest = st.rest_t_s >= par.rest_min_time_s
    return at_rest, _field_moved_at_rest(st, par, valid, at_rest)


@njit(cache=True)
def _learn_bias_at_rest(st, par, dt, gx, gy, gz):
    """At rest each gyro sample measures the bias directly, y = b + δb + white noise (R = density²/Δt), so a
    rest of T seconds averages to σ_b = density/√T. (Feeding the low-passed gyro with a small R, as VQF does,
    counts the same noise many times: the bias then snaps to whatever the low-pass holds, including the
    first second of a slow start that rest detection has not yet seen.) The per-sample variance is measured
    right here: at rest the squared deviation from the low-pass (rest_dev_gyro, 3 axes) is the sensor's own
    noise, so the same filter suits a 0.1 °/s and a 1 °/s gyro."""
    r = max(st.rest_dev_gyro / 3.0, par.rest_gyro_noise_floor_rad_s_sqrt_hz ** 2 / dt)
    # sequential scalar updates; the corrections are summed and applied once (each innovation includes the
    # bias corrections of the updates before it)
    a0 = a1 = a2 = a3 = a4 = a5 = 0.0
    b = st.gyro_bias_rad_s
    for i in range(3):
        gi = gx if i == 0 else (gy if i == 1 else gz)
        bi = a3 if i == 0 else (a4 if i == 1 else a5)
        nu = gi - b[i] - bi
        d0, d1, d2, d3, d4, d5 = scalar_update_6(st.P, E_BIAS + i, 1.0, nu, r, 0)
        a0 += d0
        a1 += d1
        a2 += d2
        a3 += d3
        a4 += d4
        a5 += d5
    _apply_correction(st, par, a0, a1, a2, a3, a4, a5)


# ----------------------------------------------------------------------------------- accelerometer: tilt only
@njit(cache=True, inline="always")
def _vertical_lowpass(st, par, dt, at_rest, ax, ay, az, wx, wy, wz, c):
    """The specific force f rotated into the estimated NED frame (f^n = C f, `c`: `dcm`'s 9-tuple) and
    low-passed there with τ = acc_lowpass_tau_s (VQF §IV-B: linear acceleration averages out, gravity stays);
    the rate about the vertical (the third row of C times the bias-corrected rate) low-passed with the same
    weight, for the lean a turn leaves (turn_lean.py); at rest |g| learned as this accelerometer sees it (its
    scale error, τ = 10 s). Returns (|f|, the low-passed f^n)."""
    e00, e01, e02, e10, e11, e12, e20, e21, e22 = c
    fn = e00 * ax + e01 * ay + e02 * az
    fe = e10 * ax + e11 * ay + e12 * az
    fd = e20 * ax + e21 * ay + e22 * az
    fnorm = math.sqrt(ax * ax + ay * ay + az * az)
    if dt > 0.0:
        lowpass_f(st.unturned, st.lp_rest.k, fn, fe, fd)   # the rest detector's weight, set this step
    if at_rest and dt > 0.0:
        st.g_ref_m_s2 += _lowpass_weight(st.lp_g_ref, dt, 10.0) * (fnorm - st.g_ref_m_s2)
    tau = par.acc_lowpass_tau_s
    if tau > 0.0 and dt > 0.0:
        ka = _lowpass_weight(st.lp_acc_ned, dt, tau)
        f = st.acc_ned_lp_m_s2
        f[0] += ka * (fn - f[0])
        f[1] += ka * (fe - f[1])
        f[2] += ka * (fd - f[2])
        un = f[0]
        ue = f[1]
        ud = f[2]
    else:
        ka = 1.0
        un = fn
        ue = fe
        ud = fd
    lowpass_rate_down(st.unmodelled, ka, e20 * wx + e21 * wy + e22 * wz)
    track_turn_speed(st.unmodelled, ka, dt, fn, fe, e00, e10)
    return fnorm, un, ue, ud


@njit(cache=True, inline="always")
def _motion_noise_rad2(st, par, dt, nu_n, nu_e):
    """Acceleration-adaptive tilt noise: the spread of the tilt innovation (nu_n, nu_e) around its running mean,
    times acc_adaptive_gain, rad². The low-passed linear acceleration is exactly (v − LP_τ(v)) / τ: the sensor's
    velocity minus its recent mean, over τ. A hand shaking or moving the sensor about leaves a residual that
    swings with the motion, not white noise; a real tilt error is a slow drift. So the spread measures the
    residual and is added to the measurement variance (covariance matching: R. K. Mehra, IEEE TAC 15(2), 1970;
    A. H. Mohamed, K. P. Schwarz, J. Geodesy 73, 1999). A persistent tilt error moves the mean, not the
    spread, so it is still corrected."""
    mean = st.acc_nu_mean_rad
    var = st.acc_nu_var_rad2
    if par.acc_adaptive_tau_s > 0.0 and dt > 0.0:
        kw = _lowpass_weight(st.lp_spread, dt, par.acc_adaptive_tau_s)
        mean[0], var[0] = _running_spread(mean[0], var[0], nu_n, kw)
        mean[1], var[1] = _running_spread(mean[1], var[1], nu_e, kw)
    return par.acc_adaptive_gain * 0.5 * (var[0] + var[1])


@njit(cache=True, inline="always")
def _vertical_accepted(st, par, dt, unorm, g_ref, nu_n, nu_e):
    """Whether the low-passed vertical (norm `unorm`, innovation nu_n, nu_e) may correct the tilt. Rejected:
    (a) a sustained push, |f| of the low-pass far from g; (b) a vertical more than the gate angle from the
    estimate (the covariance of a low-passed, correlated measurement is no honest yardstick; an angle is).
    Either way the low-pass holds the push: stay off until it has forgotten it (4 τ → 2 % left), unless
    nothing has been accepted for acc_gate_recover_s (a wrong tilt must recover)."""
    dev = abs(unorm - g_ref)  # sustained linear acceleration left after the low-pass
    if dev > par.acc_reject_m_s2 or unorm < 0.5 * g_ref or nu_n * nu_n + nu_e * nu_e > par.acc_gate_rad ** 2:
        st.acc_hold_s = 4.0 * par.acc_lowpass_tau_s
    elif st.acc_hold_s > 0.0:
        st.acc_hold_s -= dt
    if not (unorm > 0.5 * g_ref and (st.acc_hold_s <= 0.0 or st.acc_since_accept_s > par.acc_gate_recover_s)):
        st.acc_since_accept_s += dt
        return False
    return True


@njit(cache=True, inline="always")
def _vertical_noise_rad2(par, at_rest, unorm, g_ref, r_motion):
    """The tilt measurement's variance per axis, rad²: the accelerometer's noise over g (its at-rest noise at
    rest), plus the motion spread `r_motion` (`_motion_noise_rad2`), plus in motion the turn angle: a sustained
    acceleration a ⟂ g (a turn) tilts the apparent vertical by φ with cos φ = g/|f|, the size of the error the
    measurement can carry (scaled by acc_turn_noise_gain beyond acc_turn_dead_zone_rad)."""
    if at_rest:
        return (par.acc_noise_rest_m_s2 / g_ref) ** 2 + r_motion
    phi = 0.0
    if par.acc_turn_noise_gain > 0.0:
        ratio = min(unorm, g_ref) / max(unorm, g_ref)
        phi = par.acc_turn_noise_gain * max(math.acos(ratio) - par.acc_turn_dead_zone_rad, 0.0)
    return (par.acc_noise_m_s2 / g_ref) ** 2 + phi * phi + r_motion


@njit(cache=True, inline="always")
def _correct_tilt(st, par, fnorm, g_ref, nu_n, nu_e, r):
    """The vertical's two scalar updates, innovation nu_n on δθ_E (row +1) and nu_e on δθ_N (row −1), variance
    r each, with the gain on heading forced to zero; and no bias learning while |f| is off g (a push would be
    read as bias). Sequential: the second innovation is re-evaluated after the first correction; the two
    corrections are applied together."""
    mask = M_HEADING if abs(fnorm - g_ref) < par.rest_acc_th_m_s2 else (M_HEADING | M_BIAS)
    a0, a1, a2, a3, a4, a5 = scalar_update_6(st.P, E_TILT_E, 1.0, nu_n, r, mask)
    nu_e2 = nu_e + a0
    d0, d1, d2, d3, d4, d5 = scalar_update_6(st.P, E_TILT_N, -1.0, nu_e2, r, mask)
    _apply_correction(st, par, a0 + d0, a1 + d1, a2 + d2, a3 + d3, a4 + d4, a5 + d5)
    st.acc_since_accept_s = 0.0


@njit(cache=True, inline="always")
def _correct_tilt_across(st, par, fnorm, g_ref, nu_n, nu_e, r, lean_n, lean_e):
    """The vertical's update across a lean the gyro did not turn (unturned_lean.py) only: along it the specific
    force holds the speed change, across it the vertical is as good as ever. p = (−lean_e, lean_n)/|lean|, the
    horizontal direction across; the innovation p·(nu_n, nu_e) observes p_n δθ_E − p_e δθ_N (`_correct_tilt`'s
    rows), variance r; the gain on heading forced to zero, and on the bias as `_correct_tilt` does."""
    norm = math.sqrt(lean_n * lean_n + lean_e * lean_e)
    pn = -lean_e / norm
    pe = lean_n / norm
    mask = M_HEADING if abs(fnorm - g_ref) < par.rest_acc_th_m_s2 else (M_HEADING | M_BIAS)
    d0, d1, d2, d3, d4, d5 = pair_update_6(st.P, E_TILT_N, -pe, E_TILT_E, pn, pn * nu_n + pe * nu_e, r, mask)
    _apply_correction(st, par, d0, d1, d2, d3, d4, d5)
    st.acc_since_accept_s = 0.0


@njit(cache=True, inline="always")
def _sums_lean(st, par, at_rest):
    """Whether the speed change's sum (turn_lean.track_accel_push) takes this step's levelling: not at rest
    (nothing leans the vertical then) and not while the filter still converges from its initialisation
    (t_run < init_min_time_s or a tilt 1σ ≥ converged_tilt_rad, the INITIALISING test's tilt part): those
    corrections remove the error it started with, which its covariance carries, and the gyro bias it learns
    from them is the start's guess, not the drift it will explain."""
    P = st.P
    return (not at_rest and st.t_run_s >= par.init_min_time_s
            and max(P[E_TILT_N, E_TILT_N], P[E_TILT_E, E_TILT_E]) < par.converged_tilt_rad * par.converged_tilt_rad)


@njit(cache=True)
def _tilt_update(st, par, dt, at_rest, ax, ay, az, wx, wy, wz, c, publish, summing):
    """The vertical of the specific force, low-passed in the estimated NED frame (`_vertical_lowpass`), corrects
    δθ_N, δθ_E with the gain on heading forced to zero (`_correct_tilt`), with a variance that grows with the
    motion (`_motion_noise_rad2`, `_vertical_noise_rad2`). Rejected while the low-passed |f| is far from g or
    its vertical is more than acc_gate_rad from the estimate, then held off until the low-pass has forgotten
    the push (`_vertical_accepted`). (wx, wy, wz): the bias-corrected rate, for the lean a turn leaves
    (`turn_lean.track_turn_speed` on both paths, `turn_lean.track_tilt_push` only when `publish`: they feed the
    published 1σ only); c: C_b^n of the current attitude (`dcm`, 9 scalars); summing: the speed change's sum
    takes this update's correction (`_sums_lean`). Returns F_ACCEL_REJECTED or 0."""
    g_ref = st.g_ref_m_s2   # what `_vertical_lowpass` learns at rest applies from the next sample
    fnorm, un, ue, ud = _vertical_lowpass(st, par, dt, at_rest, ax, ay, az, wx, wy, wz, c)
    unorm = math.sqrt(un * un + ue * ue + ud * ud)
    # unit measured "up" in NED: u = [δθ_E, −δθ_N, −1] (+ noise)
    inv_unorm = 1.0 / unorm if unorm > 0.0 else 0.0
    nu_n = un * inv_unorm
    nu_e = ue * inv_unorm
    r_motion = _motion_noise_rad2(st, par, dt, nu_n, nu_e)
    P = st.P
    bias_var = 0.0   # read at rest only (`leans_unturned` returns before it in motion)
    if at_rest:
        bias_var = max(P[E_BIAS, E_BIAS], max(P[E_BIAS + 1, E_BIAS + 1], P[E_BIAS + 2, E_BIAS + 2]))
    leaning, lean_n, lean_e = leans_unturned(st.unturned, at_rest, dt, g_ref, st.gyro_bias_rad_s, bias_var,
                                             st.unmodelled.rate_down_lp_rad_s)
    if not _vertical_accepted(st, par, dt, unorm, g_ref, nu_n, nu_e):
        return F_ACCEL_REJECTED
    r = _vertical_noise_rad2(par, at_rest, unorm, g_ref, r_motion)
    gain_e = levelling_gain(st.P[E_TILT_E, E_TILT_E], r)
    if publish:
        track_tilt_push(st.unmodelled, turn_speed_m_s(st.unmodelled, par.turn_speed_m_s), g_ref, gain_e)
    # on both paths (a sum: no bound after a batch could stand for it), so a batch leaves the state a step leaves
    track_accel_push_kept(st.unmodelled, nu_n, nu_e, levelling_gain(st.P[E_TILT_N, E_TILT_N], r), gain_e,
                          _push_keep(st.push_keep, dt), summing)
    if leaning:   # at rest, a lean the gyro did not turn: a speed change, not the vertical (unturned_lean.py)
        _correct_tilt_across(st, par, fnorm, g_ref, nu_n, nu_e, r, lean_n, lean_e)
    else:
        _correct_tilt(st, par, fnorm, g_ref, nu_n, nu_e, r)
    return 0


# ----------------------------------------------------------------------------------- body-fixed field offset
@njit(cache=True)
def _offset_update(o, cn, cmx, cmy, cmz, r):
    """Recursive least squares for a body-fixed field offset b from two snapshots of the field: the earth
    field is constant in NED, m = C_nᵇ h + b, so C₂m₂ − C₁m₁ = (C₂ − C₁) b (the attitude's heading error
    cancels as long as it is the same at both). Three scalar rows, noise variance r (µT²) each.
    cn: C₂ = C_b^n now (`dcm`'s 9-tuple); cmx, cmy, cmz: C₂m₂. Returns the mean normalised squared innovation of
    the rows (≈ 1 when the model fits)."""
    nis = 0.0
    y = (cmx - o.cm_ut[0], cmy - o.cm_ut[1], cmz - o.cm_ut[2])
    b = o.b_ut
    p = o.P_ut2
    c1 = o.c
    for i in range(3):
        h0 = cn[3 * i] - c1[i, 0]
        h1 = cn[3 * i + 1] - c1[i, 1]
        h2 = cn[3 * i + 2] - c1[i, 2]
        ph0 = p[0, 0] * h0 + p[0, 1] * h1 + p[0, 2] * h2
        ph1 = p[1, 0] * h0 + p[1, 1] * h1 + p[1, 2] * h2
        ph2 = p[2, 0] * h0 + p[2, 1] * h1 + p[2, 2] * h2
        sv = h0 * ph0 + h1 * ph1 + h2 * ph2 + r
        nu = y[i] - (h0 * b[0] + h1 * b[1] + h2 * b[2])
        nis += nu * nu / sv
        k0 = ph0 / sv
        k1 = ph1 / sv
        k2 = ph2 / sv
        b[0] += k0 * nu
        b[1] += k1 * nu
        b[2] += k2 * nu
        p[0, 0] -= k0 * ph0
        p[0, 1] -= k0 * ph1
        p[0, 2] -= k0 * ph2
        p[1, 0] -= k1 * ph0
        p[1, 1] -= k1 * ph1
        p[1, 2] -= k1 * ph2
        p[2, 0] -= k2 * ph0
        p[2, 1] -= k2 * ph1
        p[2, 2] -= k2 * ph2
    return nis / 3.0


@njit(cache=True)
def _disagreement(o, ms, mp, fn, fe, fd):
    """How far a field (in the estimated NED frame, µT) is from the learned reference (`ms`), in units of
    the disturbance checks' tolerances: ((|m| − ref) / (tol·ref))² + (sin(dip − ref dip) / dip tol)²; > 1 is
    outside. (The sine of the dip difference, from the cached sine and cosine of the reference dip, instead of
    the difference itself: no atan2 per sample, and within 1.2 % of it up to 15°.)"""
    ref = ms.ref_norm_ut
    ref_dip = ms.ref_dip_rad
    if o.dip_cos == 0.0 or abs(ref_dip - o.dip_cached_rad) > 1e-3:
        o.dip_cached_rad = ref_dip
        o.dip_sin = math.sin(ref_dip)
        o.dip_cos = math.cos(ref_dip)
    fh = math.sqrt(fn * fn + fe * fe)
    n = math.sqrt(fh * fh + fd * fd)
    dn = (n - ref) / (mp.norm_tol * ref)
    dd = (fd * o.dip_cos - fh * o.dip_sin) / (n * mp.dip_tol_rad)
    return dn * dn + dd * dd


@njit(cache=True, inline="always")
def _turned_since_snapshot(o, par, c):
    """The attitude C₂ (`c`, `dcm`'s 9-tuple) has turned by more than mag_offset_min_angle_rad from the previous
    snapshot's C₁: cos θ = (trace(C₁ᵀ C₂) − 1) / 2 below mag_offset_min_cos (two snapshots that close tell
    nothing about b)."""
    c00, c01, c02, c10, c11, c12, c20, c21, c22 = c
    c1 = o.c
    tr = (c00 * c1[0, 0] + c01 * c1[0, 1] + c02 * c1[0, 2]
          + c10 * c1[1, 0] + c11 * c1[1, 1] + c12 * c1[1, 2]
          + c20 * c1[2, 0] + c21 * c1[2, 1] + c22 * c1[2, 2])
    return 0.5 * (tr - 1.0) < par.mag_offset_min_cos


@njit(cache=True, inline="always")
def _refit_offset(o, par, rate, mx, my, mz, c, cmx, cmy, cmz):
    """One recursive least squares step between the previous snapshot and now (`_offset_update`), forgetting
    with time constant mag_offset_tau_s; then whether b is usable: known well enough, significantly non-zero
    (Σ b²/σ² > 16: not calibration residue within the noise), and the data fit a body-fixed offset (a field
    that changes with position leaves innovations far above their predicted variance)."""
    p = o.P_ut2
    if p[0, 0] == 0.0:
        for i in range(3):
            p[i, i] = 1e4   # (100 µT)²: nothing known
    lam = math.exp(-o.since_snapshot_s / par.mag_offset_tau_s)
    for i in range(3):
        for j in range(3):
            p[i, j] = min(p[i, j] / lam, 1e4)
    # a magnetometer sampled δt apart from the gyro sees the field turned by |ω|·δt
    lag_ut = rate * par.mag_offset_lag_s * math.sqrt(mx * mx + my * my + mz * mz)
    nis = _offset_update(o, c, cmx, cmy, cmz, 2.0 * (par.mag.noise_ut ** 2 + lag_ut * lag_ut))
    o.nis += (1.0 - lam) * (nis - o.nis)
    pmax = max(p[0, 0], max(p[1, 1], p[2, 2]))
    signif = 0.0
    for i in range(3):
        signif += o.b_ut[i] ** 2 / p[i, i]
    o.ready = pmax < par.mag_offset_use_sigma_ut ** 2 and signif > 16.0 and o.nis < 4.0


@njit(cache=True, inline="always")
def _take_snapshot(o, c, cmx, cmy, cmz):
    """Keep C₁ = C (`c`, `dcm`'s 9-tuple) and C₁m₁ for the next fit step."""
    o.cm_ut[0] = cmx
    o.cm_ut[1] = cmy
    o.cm_ut[2] = cmz
    c1 = o.c
    c1[0, 0], c1[0, 1], c1[0, 2], c1[1, 0], c1[1, 1], c1[1, 2], c1[2, 0], c1[2, 1], c1[2, 2] = c
    o.snapshot_set = True
    o.since_snapshot_s = 0.0


@njit(cache=True, inline="always")
def _offset_explained_field(st, par, kd, mx, my, mz, c, cmx, cmy, cmz):
    """The field to use, body and NED (µT): with the offset subtracted (m − b, C m − C b) while b is ready and
    the corrected field's running disagreement with the reference (weight kd) is below mag_offset_explain_ratio
    times the raw field's; else the raw field."""
    o = st.offset
    if not o.ready:
        o.disagree_corrected = o.disagree_raw
        return mx, my, mz, cmx, cmy, cmz
    c00, c01, c02, c10, c11, c12, c20, c21, c22 = c
    bx = o.b_ut[0]
    by = o.b_ut[1]
    bz = o.b_ut[2]
    cbx = cmx - (c00 * bx + c01 * by + c02 * bz)
    cby = cmy - (c10 * bx + c11 * by + c12 * bz)
    cbz = cmz - (c20 * bx + c21 * by + c22 * bz)
    o.disagree_corrected += kd * (_disagreement(o, st.mag, par.mag, cbx, cby, cbz) - o.disagree_corrected)
    if o.disagree_corrected < par.mag_offset_explain_ratio * o.disagree_raw:
        return mx - bx, my - by, mz - bz, cbx, cby, cbz
    return mx, my, mz, cmx, cmy, cmz


@njit(cache=True)
def _field_offset(st, par, dt, rate, mx, my, mz):
    """Learn and, where it explains the field, remove a body-fixed field offset b (a magnet or iron attached
    after calibration: uncalibrated hard iron). Returns the field to use in the body frame (mx, my, mz) and in
    the estimated NED frame (mn, me, md), µT.

    m = C_nᵇ h + b: the norm and dip of m change with orientation, so the field disagrees with the
    reference learned before the magnet came. b is observable from rotation alone (`_offset_update`: the
    heading error cancels between two snapshots at least mag_offset_min_angle_rad apart, `_turned_since_snapshot`),
    learned by recursive least squares forgetting with time constant mag_offset_tau_s (`_refit_offset`). A fit
    also reads the residual calibration errors and the field gradients of an undisturbed work space as an
    offset of a few µT, so b is used only while it explains why the field disagrees with the reference: the
    corrected field's running disagreement (`_disagreement`, time constant mag_offset_agree_tau_s) is below
    mag_offset_explain_ratio times the raw field's (`_offset_explained_field`). An offset that leaves the
    field's norm and dip as they were is not used; nor is one fitted to a magnet in the surroundings (its
    field depends on position, not on orientation, and the fit is inconsistent); when the magnet is removed
    the raw field agrees again and b is no longer used."""
    o = st.offset
    c = dcm(st.q[0], st.q[1], st.q[2], st.q[3])
    c00, c01, c02, c10, c11, c12, c20, c21, c22 = c
    cmx = c00 * mx + c01 * my + c02 * mz
    cmy = c10 * mx + c11 * my + c12 * mz
    cmz = c20 * mx + c21 * my + c22 * mz
    if st.mag.ref_norm_ut <= 0.0:
        return mx, my, mz, cmx, cmy, cmz
    kd = _lowpass_weight(st.lp_disagree, dt, par.mag_offset_agree_tau_s) if dt > 0.0 else 0.0
    o.disagree_raw += kd * (_disagreement(o, st.mag, par.mag, cmx, cmy, cmz) - o.disagree_raw)
    o.since_snapshot_s += dt
    take = (not o.snapshot_set) or o.since_snapshot_s > 2.0
    if o.snapshot_set and _turned_since_snapshot(o, par, c):
        _refit_offset(o, par, rate, mx, my, mz, c, cmx, cmy, cmz)
        take = True
    if take:
        _take_snapshot(o, c, cmx, cmy, cmz)
    return _offset_explained_field(st, par, kd, mx, my, mz, c, cmx, cmy, cmz)


# ----------------------------------------------------------------------------------- magnetometer: heading only
@njit(cache=True)
def _heading_update(st, par, dt, rate, valid, at_rest, moved_at_rest, mx, my, mz, publish):
    """The body-fixed offset stage, then the magnetometer heading (mag_heading.py's check and measurement)
    corrects δθ_D with the gain on tilt forced to zero (row h = −e_D: α = −δθ_D). Returns flag bits."""
    flags = 0
    mag_ok = (valid & IN_MAG_OK) != 0 and par.mag_enabled
    offset_on = mag_ok and par.mag_offset_tau_s > 0.0
    mn = me = md = 0.0
    if offset_on:
        mx, my, mz, mn, me, md = _field_offset(st, par, dt, rate, mx, my, mz)
    used = False
    if mag_ok:
        if not offset_on:
            mn, me, md = rotate_to_ned(st.q[0], st.q[1], st.q[2], st.q[3], mx, my, mz)
        mnorm = math.sqrt(mx * mx + my * my + mz * mz)
        res, alpha, r = mag.heading_measurement(st.mag, par.mag, dt, rate, at_rest, moved_at_rest,
                                                mn, me, md, mnorm, 0.0, st.P[E_HEADING, E_HEADING])
        if res == mag.MAG_USE:
            if publish:
                track_heading_push(st.unmodelled, st.mag.ref_dip_rad, st.P[E_HEADING, E_HEADING], r)
            d0, d1, d2, d3, d4, d5 = scalar_update_6(st.P, E_HEADING, -1.0, alpha, r, M_TILT)
            _apply_correction(st, par, d0, d1, d2, d3, d4, d5)
            used = True
        elif res == mag.MAG_REJECTED:
            flags |= F_MAG_REJECTED
    if mag.heading_bookkeeping(st.mag, par.mag, dt, used):
        flags |= F_MAG_UNAVAILABLE
    return flags


# ----------------------------------------------------------------------------------- the step
@njit(cache=True)
def _output_quaternion(st, out):
    """out.q ← the attitude quaternion with its scalar ≥ 0; returns it."""
    q0 = st.q[0]
    q1 = st.q[1]
    q2 = st.q[2]
    q3 = st.q[3]
    if q0 < 0.0:
        q0 = -q0
        q1 = -q1
        q2 = -q2
        q3 = -q3
    out.q[0] = q0
    out.q[1] = q1
    out.q[2] = q2
    out.q[3] = q3
    return q0, q1, q2, q3


@njit(cache=True)
def _yaw_cos_sin(q0, q1, q2, q3):
    """cos and sin of the yaw of q: C00, C10 over their norm (no atan2, cos, sin on the hot path)."""
    cy = 1.0 - 2.0 * (q2 * q2 + q3 * q3)
    sy = 2.0 * (q1 * q2 + q0 * q3)
    hy = math.sqrt(cy * cy + sy * sy)
    if hy > 1e-12:
        return cy / hy, sy / hy
    return 1.0, 0.0


@njit(cache=True)
def _converging(st, par, cy, sy):
    """INITIALISING by the filter's own covariance (the unmodelled terms of the published 1σ are not something
    it converges on): 1σ roll/pitch from the NED tilt covariance rotated into the heading frame (cy, sy: cos,
    sin of yaw), 1σ yaw from δθ_D."""
    P = st.P
    sig_roll, sig_pitch = tilt_sigma(cy, sy, P[E_TILT_N, E_TILT_N], P[E_TILT_N, E_TILT_E], P[E_TILT_E, E_TILT_E])
    return initialising(st.t_run_s, sig_roll, sig_pitch, math.sqrt(max(P[E_HEADING, E_HEADING], 0.0)),
                        par.init_min_time_s, par.converged_tilt_rad, par.mag_enabled, par.converged_yaw_rad)


@njit(cache=True)
def _fill_outputs(st, par, gx, gy, gz, out):
    """Everything the one-sample path publishes: quaternion (scalar ≥ 0), bias-corrected rate, 1σ roll/pitch/yaw,
    bias. Returns F_INITIALISING or 0."""
    q0, q1, q2, q3 = _output_quaternion(st, out)
    b = st.gyro_bias_rad_s
    wx = gx - b[0]
    wy = gy - b[1]
    wz = gz - b[2]
    out.rate_rad_s[0] = wx
    out.rate_rad_s[1] = wy
    out.rate_rad_s[2] = wz
    out.gyro_bias_rad_s[0] = b[0]
    out.gyro_bias_rad_s[1] = b[1]
    out.gyro_bias_rad_s[2] = b[2]
    cy, sy = _yaw_cos_sin(q0, q1, q2, q3)
    init = _converging(st, par, cy, sy)
    # the published 1σ adds what the covariance does not carry (Schmidt's "consider" terms):
    # (a) the low-passed vertical is on average acc_lowpass_tau_s old, so it has not seen the attitude random
    #     walk of the last τ: the tilt process noise over τ;
    # (b) the lean a turn or a speed change has left in the tilt and, through the dip, in the heading
    #     (`turn_lean.track_tilt_push`, `turn_lean.track_accel_push`), and the drift of the gyro bias learnt from
    #     motion while no levelling corrects it (`turn_lean.track_lean_bias_drift`)
    # (c) the accelerometer's own bias, which no state carries: the levelling takes the vertical as f/|f|, so a
    #     horizontal bias b tilts it by b/g about each horizontal axis (Groves 2013 §5.6.2, attitude
    #     initialisation: the levelling error δθ ≈ b_a/g), and through the dip a tilt about north turns the
    #     field's vertical part into east: a heading error tan(I)·b/g (with the magnetometer only)
    u = st.unmodelled
    acc_bias_tilt_rad = par.accel_bias_sigma_m_s2 / st.g_ref_m_s2
    acc_bias_tilt_rad2 = acc_bias_tilt_rad * acc_bias_tilt_rad
    extra = (_tilt_process_noise_rad2(par, math.sqrt(wx * wx + wy * wy + wz * wz), par.acc_lowpass_tau_s)
             + tilt_pushes_rad(u) ** 2 + acc_bias_tilt_rad2)
    P = st.P
    sig = out.sigma_rpy_rad
    sig[0], sig[1] = tilt_sigma(cy, sy, P[E_TILT_N, E_TILT_N] + extra, P[E_TILT_N, E_TILT_E],
                                P[E_TILT_E, E_TILT_E] + extra)
    # (e) the accelerometer's misalignment, which no state carries either: the levelled vertical is the measured
    #     force's direction, turned by it (accel_axes_tilt.py), at the low-passed force the levelling uses
    if par.accel_axes_tilt_sigma_rad > 0.0:
        f = st.acc_ned_lp_m_s2
        var_roll, var_pitch = accel_axes_tilt_variance_in_force_rad2(dcm(q0, q1, q2, q3), f[0], f[1], f[2],
                                                                     par.accel_axes_tilt_sigma_rad)
        sig[0] = math.sqrt(sig[0] * sig[0] + var_roll)
        sig[1] = math.sqrt(sig[1] * sig[1] + var_pitch)
    # (d) the heading error the magnetometer calibration left, which no magnetometer update can show
    #     (calibration_heading.py)
    cal = 0.0
    if par.mag_enabled:
        tan_dip = math.tan(st.mag.ref_dip_rad)
        cal = par.heading_calibration_var_rad2 + tan_dip * tan_dip * acc_bias_tilt_rad2
    sig[2] = math.sqrt(max(P[E_HEADING, E_HEADING], 0.0) + u.heading_push_rad * u.heading_push_rad + cal)
    return F_INITIALISING if init else 0


@njit(cache=True)
def _fill_estimate(st, par, out):
    """What the batch returns, nothing more: the quaternion (scalar ≥ 0) into out.q, and F_INITIALISING or 0
    exactly as `_fill_outputs` decides it."""
    q0, q1, q2, q3 = _output_quaternion(st, out)
    if st.t_run_s < par.init_min_time_s:   # `initialising` holds whatever the 1σ: do not compute them
        return F_INITIALISING
    # converged beyond doubt without the 1σ: the roll and pitch variances (the tilt block in a unit-vector
    # direction, cos² + sin² = 1) are at most max(P_NN, P_EE) + |P_NE|; with a 1 % margin over every rounding
    # of `_converging` this decides only where it would decide the same
    P = st.P
    tilt_bound = max(P[E_TILT_N, E_TILT_N], P[E_TILT_E, E_TILT_E]) + abs(P[E_TILT_N, E_TILT_E])
    if tilt_bound < 0.99 * par.converged_tilt_rad ** 2 and (
            not par.mag_enabled or P[E_HEADING, E_HEADING] < 0.99 * par.converged_yaw_rad ** 2):
        return 0
    cy, sy = _yaw_cos_sin(q0, q1, q2, q3)
    return F_INITIALISING if _converging(st, par, cy, sy) else 0


@njit(cache=True)
def mekf_step(st, par, t_s, gx, gy, gz, ax, ay, az, mx, my, mz, sample_flags, out, publish):
    """One sample through the stages (module docstring). st, par, out: MEKF_STATE_DTYPE, MEKF_PARAMS_DTYPE,
    MEKF_OUT_DTYPE records. sample_flags: the sample's SampleFlags as an int (invalid or saturated sensors are
    not used). publish: track the published 1σ's unmodelled terms (turn_lean.py: the lean a turn leaves) and
    fill every output (`_fill_outputs`: the one-sample path), or neither (the batch returns only the
    quaternion, `_fill_estimate`, and bounds those terms at its end: `turn_lean.bound_pushes`); the quaternion,
    the flags and the rest of the state are the same either way.
    Returns EstimateFlags bits (| NEEDS_INIT when the caller must initialise first)."""
    valid = input_validity(sample_flags, gx, gy, gz, ax, ay, az, mx, my, mz)
    dt, flags = step_dt(t_s - st.t_last_s, par.large_dt_s, par.reinit_dt_s)
    if flags & NEEDS_INIT:
        return flags
    st.t_last_s = t_s
    st.t_run_s += dt
    glast = st.gyro_last_rad_s
    if valid & IN_GYRO_OK:
        glast[0] = gx
        glast[1] = gy
        glast[2] = gz
    else:
        gx = glast[0]
        gy = glast[1]
        gz = glast[2]
    b = st.gyro_bias_rad_s
    b0 = b[0]   # the bias the step propagates with and its variance: what its updates learn of its prior is
    b1 = b[1]   # credited to the speed change's sum (turn_lean.track_bias_learning)
    b2 = b[2]
    P = st.P
    pb0 = P[E_BIAS, E_BIAS]
    pb1 = P[E_BIAS + 1, E_BIAS + 1]
    pb2 = P[E_BIAS + 2, E_BIAS + 2]
    wx = gx - b0
    wy = gy - b1
    wz = gz - b2
    rate = math.sqrt(wx * wx + wy * wy + wz * wz)
    if dt > 0.0:
        _propagate_attitude(st.q, dt, wx, wy, wz, rate)
    # C_b^n of the propagated attitude: the covariance's Φ and, unless the bias update at rest turns the
    # attitude, the frame of the tilt update (computed once for both)
    c = dcm(st.q[0], st.q[1], st.q[2], st.q[3])
    if dt > 0.0:
        _propagate_covariance(st.P, par, dt, rate, c)
    at_rest, mag_moved_at_rest = _detect_rest(st, par, dt, valid, gx, gy, gz, ax, ay, az, mx, my, mz)
    rb0 = rb1 = rb2 = 0.0
    if at_rest:
        flags |= F_AT_REST
        _learn_bias_at_rest(st, par, dt, gx, gy, gz)
        c = dcm(st.q[0], st.q[1], st.q[2], st.q[3])
        rb0 = b[0] - b0   # what rest learnt this step (turn_lean.track_lean_bias_drift)
        rb1 = b[1] - b1
        rb2 = b[2] - b2
    summing = _sums_lean(st, par, at_rest)
    levelled = False
    if valid & IN_ACC_OK:
        tilt_flags = _tilt_update(st, par, dt, at_rest, ax, ay, az, wx, wy, wz, c, publish, summing)
        flags |= tilt_flags
        levelled = tilt_flags == 0
    flags |= _heading_update(st, par, dt, rate, valid, at_rest, mag_moved_at_rest, mx, my, mz, publish)
    # on both paths, as the sum itself (`_tilt_update`)
    qb = par.gyro_bias_walk_rad_s_sqrt_s * par.gyro_bias_walk_rad_s_sqrt_s * dt
    s0 = prior_share(pb0, qb, P[E_BIAS, E_BIAS])
    s1 = prior_share(pb1, qb, P[E_BIAS + 1, E_BIAS + 1])
    s2 = prior_share(pb2, qb, P[E_BIAS + 2, E_BIAS + 2])
    db0 = b[0] - b0
    db1 = b[1] - b1
    db2 = b[2] - b2
    track_bias_learning(st.unmodelled, dt, c, summing, s0 * db0, s1 * db1, s2 * db2)
    # rest.keep is read at rest only: no exp on the steps in motion
    keep_rest = math.exp(-dt / par.rest_filter_tau_s) if at_rest else 1.0
    track_lean_bias_drift(st.unmodelled, dt, c, summing, levelled or at_rest,
                          ((1.0 - s0) * db0, (1.0 - s1) * db1, (1.0 - s2) * db2),
                          RestLearning(at_rest, keep_rest, (rb0, rb1, rb2)))
    if publish:
        return flags | _fill_outputs(st, par, gx, gy, gz, out)
    return flags | _fill_estimate(st, par, out)


@njit(cache=True)
def mekf_step_full(buf, t_s, gyro, acc, mag_ut, sample_flags):
    """`mekf_step` on the 1-element MEKF_BUFFER_DTYPE array `buf` for one sample's (3,) vectors (the one-sample
    path). Leaves out.euler_rad: `fill_euler` fills it when someone reads the angles (publishers do, at their
    rates, not at the sample rate). Returns BAD_SHAPE if a vector does not have 3 elements (nothing changed)."""
    if gyro.shape[0] != 3 or acc.shape[0] != 3 or mag_ut.shape[0] != 3:
        return BAD_SHAPE
    b = borrowed(buf)[0]   # the caller holds buf for the call: no reference counting in the step
    return mekf_step(b.state, b.par, t_s, gyro[0], gyro[1], gyro[2], acc[0], acc[1], acc[2],
                     mag_ut[0], mag_ut[1], mag_ut[2], sample_flags, b.out, True)


@njit(cache=True, inline="always")
def _fill_euler(out):
    """out.euler_rad ← the ZYX Euler angles (roll, pitch, yaw magnetic) of out.q."""
    roll, pitch, yaw = euler_zyx(out.q[0], out.q[1], out.q[2], out.q[3])
    out.euler_rad[0] = roll
    out.euler_rad[1] = pitch
    out.euler_rad[2] = yaw


@njit(cache=True)
def fill_euler(buf):
    """The ZYX Euler angles (roll, pitch, yaw magnetic) of the output quaternion of the 1-element
    MEKF_BUFFER_DTYPE array `buf` into its out.euler_rad."""
    _fill_euler(borrowed(buf)[0].out)


@njit(cache=True)
def fill_outputs_after_init(buf):
    """Every output of the 1-element MEKF_BUFFER_DTYPE array `buf` from its state, as a one-sample step fills
    them (`_fill_outputs`, the Euler angles too), the rate from the last gyro sample: an initialisation sets the
    state without a step."""
    b = borrowed(buf)[0]
    st = b.state
    g = st.gyro_last_rad_s
    _fill_outputs(st, b.par, g[0], g[1], g[2], b.out)
    _fill_euler(b.out)


@njit(cache=True)
def mekf_run(buf, scratch_out, t_s, gyro, acc, mag_ut, sample_flags, start, q_out, flags_out):
    """Run `mekf_step` over samples start… on the state and parameters of the 1-element MEKF_BUFFER_DTYPE
    array `buf` (its outputs untouched: each step's quaternion goes to the 1-element MEKF_OUT_DTYPE array
    `scratch_out`), computing only what it returns: no output but the quaternion, and the published 1σ's
    unmodelled terms bounded at the end (`turn_lean.bound_pushes`) instead of tracked per sample.
    Returns the index of the first sample that needs (re-)initialisation, or len(t_s) when all were processed.
    sample_flags (N,) int64 SampleFlags; q_out (N, 4), flags_out (N,)."""
    # views without reference counting (`borrowed`): the arrays are the caller's, held for the whole call
    b = borrowed(buf)[0]
    st = b.state
    par = b.par
    out = borrowed(scratch_out)[0]
    u = st.unmodelled
    # the extremes of what the unmodelled terms' targets are made of, over the states the batch passes through
    rate_max = abs(u.rate_down_lp_rad_s)
    speed_max = turn_speed_m_s(u, par.turn_speed_m_s)
    g_min = st.g_ref_m_s2
    dip_max = abs(st.mag.ref_dip_rad)
    n = t_s.shape[0]
    for i in range(start, n):
        f = mekf_step(
            st, par, t_s[i],
            gyro[i, 0], gyro[i, 1], gyro[i, 2],
            acc[i, 0], acc[i, 1], acc[i, 2],
            mag_ut[i, 0], mag_ut[i, 1], mag_ut[i, 2],
            sample_flags[i], out, False,
        )
        if f & NEEDS_INIT:
            bound_pushes(u, speed_max, rate_max, g_min, dip_max)
            return i
        rate_max = max(rate_max, abs(u.rate_down_lp_rad_s))
        speed_max = max(speed_max, turn_speed_m_s(u, par.turn_speed_m_s))
        g_min = min(g_min, st.g_ref_m_s2)
        dip_max = max(dip_max, abs(st.mag.ref_dip_rad))
        for j in range(4):
            q_out[i, j] = out.q[j]
        flags_out[i] = f
    bound_pushes(u, speed_max, rate_max, g_min, dip_max)
    return n


_FAST = {}   # the entry points, once looked up (each Mekf() asks for them)


def fast_step():
    """`mekf_step_full` as a directly callable compiled entry point for one-sample calls (kernel_entry.py;
    looked up once per process). The buffer is the caller's own, and the caller passes only float64 vectors
    (dtype checked; their length is checked in the kernel)."""
    if "step" not in _FAST:
        # the vectors in any layout (float64[:]): a sample's vectors may be strided views of a larger array
        vector = types.float64[:]
        _FAST["step"] = entry_point(mekf_step_full, (_buffer_type(), types.float64, vector, vector, vector,
                                                     types.int64))
    return _FAST["step"]


def fast_fill_euler():
    """`fill_euler` as a directly callable compiled entry point (as `fast_step`)."""
    if "euler" not in _FAST:
        _FAST["euler"] = entry_point(fill_euler, (_buffer_type(),))
    return _FAST["euler"]


def fast_fill_after_init():
    """`fill_outputs_after_init` as a directly callable compiled entry point (as `fast_step`)."""
    if "after_init" not in _FAST:
        _FAST["after_init"] = entry_point(fill_outputs_after_init, (_buffer_type(),))
    return _FAST["after_init"]


def _buffer_type():
    return typeof(np.zeros(1, MEKF_BUFFER_DTYPE))
