"""The `ins` estimator's compiled kernels (numba): NED strapdown mechanisation, 33-state error covariance,
accelerometer levelling while unaided, magnetometer heading, and the delayed GNSS velocity/position fusion.

`ins.py` owns the parameters, initialisation, input checks and the Estimator interface; this module is the
arithmetic. The nominal state and its bookkeeping `x` is an INS_STATE_DTYPE record, the parameters `par` an
INS_PARAMS_DTYPE record (numpy structured types: named fields that numba compiles to fixed offsets), `hist`
a ring of INS_HISTORY_DTYPE records (past nominal states for fusing a fix at its time of validity), `P` the
33×33 error covariance, `out` the per-step outputs (an INS_OUT_DTYPE record). The entry points (`ins_step`,
`fuse_gnss`) take the state and parameters (and `ins_step` the outputs) as 1-element arrays (an array unboxes
cheaper than a record).

Nominal state: attitude q (body FRD → true-north NED, Hamilton scalar first), NED velocity v, WGS-84 geodetic
position (L, λ, h), gyro bias b_g, accelerometer bias b_a (body frame), gyro scale factors and misalignment, the
accelerometer z axis's lean.
Error state δx (N_ERR = 33, true − estimate), in this order:
  δθ (0–2)  attitude error in NED, C_true = (I + [δθ×]) C_est; tilt δθ_N, δθ_E, heading δθ_D
  δv (3–5)  velocity error, NED, m/s
  δp (6–8)  position error, NED, m
  δb_g (9–11) gyro bias error, rad/s;  δb_a (12–14) accelerometer bias error, m/s²
  δs_g (15–17) gyro scale-factor error (ω_meas = (I + diag(s) + M) ω + b), fraction
  δm_g (18–23) gyro misalignment M's off-diagonal elements xy, xz, yx, yz, zx, zy (ω_j picks up m_jk ω_k), rad
  δe_m (24–28) the calibrated magnetometer's heading error harmonics c0, c1, s1, c2, s2 (mag_harmonics.py), rad
  δε_m (29–30) the calibrated magnetometer's frame tilt about body x, y (mag_frame_tilt.py), rad
  δm_a (31–32) the accelerometer z axis's lean towards x and y: its misalignment elements m_zx, m_zy
            (f_meas = (I + diag(s) + M_a) f + b_a, the simulator's and Groves eq. 4.16's M), rad
Error dynamics (Groves 2nd ed. ch. 14; the ω_in^n × δθ, Coriolis and gravity-gradient couplings are
below the ADIS16405's noise over the filter's time constants and are left out):
  δθ̇ = −C δb_g − C diag(ω) δs_g − C W(ω) δm_g + w_g,  δv̇ = −[f^n×] δθ − C δb_a − C e_z (f_x δm_zx + f_y δm_zy)
  + w_a,  δṗ = δv,  biases, scale factors, misalignments and magnetometer harmonics random walks, the frame tilt and
  the accelerometer's lean constant (W(ω): the 3×6 map of δm_g into δω). An uncalibrated 0.3 %
  gyro scale error turns into 0.07 °/s of attitude drift in a 13 °/s turn, a 0.1° misalignment of the x or
  y gyro towards z into 0.02 °/s of tilt drift — in a long turn a lean the GNSS must keep correcting; with
  these states the GNSS learns both (the turn itself makes them observable).
The covariance is propagated every `cov_period_s` (not every sample) with the transition matrix of the whole
interval built from the summed increments ∫C dt and ΔV^n = ∫f^n dt (first order in the interval, plus the
½T terms of the position rows); the magnetometer and the accelerometer levelling update at that rate too.
After each measurement update the error state is folded into the nominal state and reset (closed loop).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from . import mag_heading as mag
from .gsf_yaw import gsf_accumulate_imu_xyz
from .ins_mechanisation import (
    earth_rate_ned,
    normal_gravity_m_s2,
    position_rates,
    SPHERE_RADIUS_M,
    radii_of_curvature_m,
    transport_rate_ned,
    velocity_rate_ned,
)
from .constrained_update import residual, scalar_update
from .kernel_entry import argument_types, entry_point
from .kernel_flags import (
    F_ACCEL_REJECTED,
    F_GNSS_AIDED,
    F_GNSS_OUTAGE,
    F_INITIALISING,
    F_LARGE_DT,
    F_MAG_REJECTED,
    F_MAG_UNAVAILABLE,
    IN_ACC_OK,
    IN_GYRO_OK,
    IN_MAG_OK,
    NEEDS_INIT,
    initialising,
    input_validity,
    step_dt,
)
from .mag_frame_tilt import N_MAG_FRAME_TILT, frame_tilt_partials
from .mag_harmonics import N_MAG_HARMONICS, harmonic_basis, heading_error_rad
from .mag_rotation import rotation_vector_step
from .kernel_rotations import dcm, euler_and_tilt_sigma, normalised, quat_mul, rotate_to_ned, rotvec_quat
from .turn_lean import (
    TURN_LEAN_DTYPE,
    add_pushes_to_sigma,
    clear,
    levelling_gain,
    lowpass_rate_down,
    track_heading_push,
    track_tilt_push,
)

E_TH, E_V, E_P, E_BG, E_BA, E_SG, E_MG, E_MH = 0, 3, 6, 9, 12, 15, 18, 24
E_MF = E_MH + N_MAG_HARMONICS
# the accelerometer z axis's lean towards body x and y (its misalignment elements m_zx, m_zy), rad: the z axis reads
# m_zx f_x + m_zy f_y more, which in a horizontal acceleration a the GNSS's vertical channel cannot tell from a tilt
# of m_zx (docs/estimator.md "The accelerometer z axis's lean as states")
E_AZ_LEAN = E_MF + N_MAG_FRAME_TILT
N_ACC_Z_LEAN = 2
N_ERR = E_AZ_LEAN + N_ACC_Z_LEAN
E_TILT_N, E_TILT_E, E_YAW = E_TH, E_TH + 1, E_TH + 2     # δθ_N, δθ_E, δθ_D (the yaw error about down)
# (row j, column k) of each misalignment error component E_MG + n: δω_j = δm_jk ω_k
MIS_ROW = (0, 0, 1, 1, 2, 2)
MIS_COL = (1, 2, 0, 2, 0, 1)

# ----------------------------------------------------------------------------------- nominal state
# the GNSS gate's bookkeeping for one quantity (velocity, position)
GNSS_GATE_DTYPE = np.dtype([
    ("rejected_since_s", np.float64),   # time of validity of the first of the current run of rejections (NaN: none)
    ("nis", np.float64),                # normalised innovation squared of the last fusion attempt (diagnostic)
])

INS_STATE_DTYPE = np.dtype([
    ("q", np.float64, (4,)),                     # attitude body → true NED
    ("vel_ned_m_s", np.float64, (3,)),
    ("lat_rad", np.float64),
    ("lon_rad", np.float64),
    ("h_m", np.float64),                         # height above the ellipsoid
    ("gyro_bias_rad_s", np.float64, (3,)),
    # the gyro bias the GNSS yaw bank is corrected with: the last one a GNSS yaw confirmed (the start-up one
    # before), never what the magnetometer alone taught the filter (`Ins._monitor_decision`)
    ("bank_gyro_bias_rad_s", np.float64, (3,)),
    ("accel_bias_m_s2", np.float64, (3,)),       # body frame
    ("gyro_scale", np.float64, (3,)),            # scale-factor errors (ω_meas = (I + diag(s) + M) ω + b), fraction
    ("gyro_misalignment_rad", np.float64, (6,)),  # M: xy, xz, yx, yz, zx, zy (MIS_ROW, MIS_COL)
    ("accel_z_lean_rad", np.float64, (N_ACC_Z_LEAN,)),   # the accelerometer's m_zx, m_zy (error states E_AZ_LEAN…)
    ("t_last_s", np.float64),                    # time of the previous sample
    ("t_run_s", np.float64),                     # time since initialisation
    # sums since the last covariance propagation
    ("cov_t_s", np.float64),                     # time accumulated
    ("cov_c_s", np.float64, (9,)),               # ∫ C_b^n dt (row-major)
    ("cov_dv_m_s", np.float64, (3,)),            # ∫ f^n dt
    ("cov_c_omega_rad", np.float64, (27,)),      # ∫ C_ij ω_k dt (index 9 i + 3 j + k)
    ("cov_c_f_m_s", np.float64, (6,)),           # ∫ C_iz f_k dt, k = x, y (index 2 i + k): the lean's partials
    # levelling
    ("acc_ned_lp_m_s2", np.float64, (3,)),       # specific force low-passed in the estimated NED frame
    ("acc_hold_s", np.float64),                  # levelling stays off this much longer after a sustained push
    ("acc_since_accept_s", np.float64),          # time since the last accepted levelling update
    ("turn_lean", TURN_LEAN_DTYPE),              # the lean levelling leaves in a turn (published 1σ only)
    # last valid samples
    ("gyro_last_rad_s", np.float64, (3,)),
    ("acc_last_m_s2", np.float64, (3,)),
    ("mag_last_ut", np.float64, (3,)),           # NaN: none yet
    # the gyro's rotation since the last heading check (raw rates; Ins._mag_rotation_check reads and clears it)
    ("gyro_rotation_rad", np.float64, (3,)),
    ("gyro_rotation_s", np.float64),
    ("gyro_rotation_last_t_s", np.float64),      # NaN: none yet
    # GNSS
    ("nav_ok", np.float64),                      # 1.0 once velocity/position have been set from a fix
    ("was_aided", np.float64),                   # 1.0 once a fix has been fused (GNSS_OUTAGE only after that)
    ("gnss_fused_t_s", np.float64),              # time of validity of the last fused fix (−inf: none)
    ("last_fix_t_s", np.float64),                # time of validity of the last fix offered (accepted or not)
    ("vel_gate", GNSS_GATE_DTYPE),
    ("pos_gate", GNSS_GATE_DTYPE),
    ("hist_newest", np.float64),                 # index of the newest history row
    ("hist_count", np.float64),                  # rows of history filled
    ("mag", mag.MAG_HEADING_STATE_DTYPE),        # the magnetometer heading check
    # the calibrated magnetometer's heading error c0, c1, s1, c2, s2 (mag_harmonics.py; error states E_MH…)
    ("mag_heading_error_rad", np.float64, (N_MAG_HARMONICS,)),
    # the calibrated magnetometer's frame tilt about body x, y (mag_frame_tilt.py; error states E_MF…)
    ("mag_frame_tilt_rad", np.float64, (N_MAG_FRAME_TILT,)),
])

# ----------------------------------------------------------------------------------- history ring buffer
H_LEN = 1024       # rows: 1.25 s at 819.2 SPS (fixes older than the oldest row are not fused)
INS_HISTORY_DTYPE = np.dtype([
    ("t_s", np.float64),
    ("q", np.float64, (4,)),
    ("vel_ned_m_s", np.float64, (3,)),
    ("lat_rad", np.float64),
    ("lon_rad", np.float64),
    ("h_m", np.float64),
    ("rate_rad_s", np.float64, (3,)),            # bias-corrected body rate (lever arm)
])

# ----------------------------------------------------------------------------------- parameters
# InsParams' fields of the same names where there is one (ins.py documents each), as the kernel reads them
INS_PARAMS_DTYPE = np.dtype([
    ("gyro_noise_rad_s_sqrt_hz", np.float64),
    ("gyro_bias_walk_rad_s_sqrt_s", np.float64),
    ("accel_noise_m_s2_sqrt_hz", np.float64),
    ("accel_bias_walk_m_s2_sqrt_s", np.float64),
    ("gyro_bias_clip_rad_s", np.float64),
    ("accel_bias_clip_m_s2", np.float64),
    ("gyro_scale_walk_sqrt_s", np.float64),      # 0 while the scale factors are not estimated
    ("gyro_scale_clip", np.float64),             # |s| and |m| limit per element
    ("gyro_misalignment_walk_rad_sqrt_s", np.float64),
    ("cov_period_s", np.float64),                # covariance propagation period
    ("earth_rotation", np.float64),              # 1.0: rotating Earth (Earth rate, transport rate, Coriolis)
    ("sphere", np.float64),                      # 1.0: spherical Earth (R0 = 6 378 137 m), else WGS-84 radii
    ("level_noise_m_s2", np.float64),
    ("level_reject_m_s2", np.float64),
    ("level_gate_rad", np.float64),
    ("level_lowpass_tau_s", np.float64),
    ("level_recover_s", np.float64),
    ("turn_speed_m_s", np.float64),              # the speed a turn's lean is reckoned at while levelling
    ("mag_enabled", np.float64),                 # 1.0: magnetometer heading updates
    ("mag_use", np.float64),                     # 1.0: fuse the heading; 0.0: the heading monitor rejects it
    ("mag_moves_tilt", np.float64),              # 1.0: while aided the heading update may move the tilt
    ("mag_bias_var_rad2", np.float64),           # slowly varying part of the heading error (calibration)
    ("mag_bias_tau_s", np.float64),              # its correlation time: noise inflated by τ/Δt (_mag_update)
    ("mag_harmonics_on", np.float64),            # 1.0: the heading error is the E_MH states (mag_harmonics.py)
    ("mag_harmonic_walk_rad_sqrt_s", np.float64),   # their random walk
    ("mag_harmonic_residual_var_rad2", np.float64),  # the part they leave, fused as mag_bias_var is without them
    ("mag_frame_tilt_on", np.float64),           # 1.0: the calibration's frame tilt is the E_MF states (mag_frame_tilt.py)
    ("iron_ut", np.float64, (3,)),               # learned hard iron removed before use (body frame)
    ("iron_soft_inv", np.float64, (3, 3)),       # (I + D)⁻¹ of the learned soft iron, applied after the hard iron
    ("mag", mag.MAG_HEADING_PARAMS_DTYPE),       # the magnetometer heading check
    ("declination_rad", np.float64),             # true = magnetic + declination
    ("lever_arm_m", np.float64, (3,)),           # antenna position in the body frame relative to the IMU
    ("lever_arm_cov_m2", np.float64, (3, 3)),    # the arm's own uncertainty (covariance of its error), m²: the
                                                 # fixes' R gains what it makes of them (`_arm_consider`)
    ("lever_arm_corr_s", np.float64),            # the span its term is one error over (lever_arm_consider.py)
    ("gate_chi2", np.float64, (3,)),             # innovation gate (χ² threshold) for 1, 2, 3 degrees of freedom
    ("reject_reset_s", np.float64),
    ("dead_reckon_s", np.float64),
    ("outage_reset_s", np.float64),
    ("nav_drop_s", np.float64),
    ("max_delay_s", np.float64),
    ("gnss_timeout_s", np.float64),
    ("nav_init_sigma_tilt_rad", np.float64),
    ("gnss_yaw", np.float64),                    # 1.0: run the Gaussian-sum GNSS yaw bank beside the filter
    ("large_dt_s", np.float64),
    ("reinit_dt_s", np.float64),
    ("init_min_time_s", np.float64),
    ("converged_tilt_rad", np.float64),
    ("converged_yaw_rad", np.float64),
    ("accel_bias_learn", np.float64),            # 1.0: GNSS updates move the accelerometer bias (the heading is known)
])

# ----------------------------------------------------------------------------------- outputs (per step)
INS_OUT_DTYPE = np.dtype([
    ("q", np.float64, (4,)),                 # body → magnetic NED (the AttitudeEstimate convention), scalar ≥ 0
    ("rate_rad_s", np.float64, (3,)),        # bias-corrected rate, body
    ("sigma_rpy_rad", np.float64, (3,)),     # roll, pitch, yaw 1σ
    ("gyro_bias_rad_s", np.float64, (3,)),
    ("euler_rad", np.float64, (3,)),         # roll, pitch, yaw (ZYX, yaw true)
    ("vel_ned_m_s", np.float64, (3,)),
    ("lat_rad", np.float64),
    ("lon_rad", np.float64),
    ("h_m", np.float64),                     # height above the WGS-84 ellipsoid
    ("sigma_vel_m_s", np.float64, (3,)),     # 1σ north, east, down
    ("sigma_pos_m", np.float64, (3,)),       # 1σ north, east, down
    ("accel_bias_m_s2", np.float64, (3,)),   # body frame
])

# ----------------------------------------------------------------------------------- GNSS fusion results (bits)
R_VEL_FUSED = 1
R_POS_FUSED = 2
R_VEL_REJECTED = 4
R_POS_REJECTED = 8
R_VEL_RESET = 16       # a persistent change: velocity reset to the fix after a run of rejections
R_POS_RESET = 32
R_NAV_INIT = 64        # first fix: velocity and position set from it
R_TOO_OLD = 128        # older than the history (or than max_delay_s): not fused
R_OUTAGE_RESET = 256   # first fix after an outage: velocity and position set from it, attitude untouched

# error-state component masks (bit i = error-state component i) for `scalar_update`
M_TILT = 0b11 << E_TH           # δθ_N, δθ_E
M_HEADING = 0b100 << E_TH       # δθ_D
M_GYRO_BIAS = 0b111 << E_BG
M_ACC_BIAS = 0b111 << E_BA
M_ACC_BIAS_XY = 0b011 << E_BA   # body x, y: the axes a near-level vehicle's yaw error trades with
M_GYRO_SCALE = 0b111 << E_SG
M_GYRO_MIS = 0b111111 << E_MG
# m_xz, m_yz (MIS_ROW/MIS_COL 1 and 3): what the x and y gyros pick up of the turn rate, the elements that keep a
# tilt error fixed in the body through a turn (the third member of the pitch / forward-bias pair)
M_GYRO_MIS_TURN = (1 << (E_MG + 1)) | (1 << (E_MG + 3))
M_NAV = 0b111111 << E_V
M_MAG_HARMONICS = ((1 << N_MAG_HARMONICS) - 1) << E_MH
M_MAG_FRAME_TILT = ((1 << N_MAG_FRAME_TILT) - 1) << E_MF
M_ACC_Z_LEAN = ((1 << N_ACC_Z_LEAN) - 1) << E_AZ_LEAN
NAV_UNKNOWN_VAR_V = 100.0    # (10 m/s)², velocity variance before a fix sets it
NAV_UNKNOWN_VAR_P = 1e6      # (1 km)², position variance before a fix sets it


# ----------------------------------------------------------------------------------- small helpers
@njit(cache=True)
def _radii(par, lat):
    """(R_N, R_E) of the configured Earth model, m."""
    if par.sphere > 0.0:
        return SPHERE_RADIUS_M, SPHERE_RADIUS_M
    return radii_of_curvature_m(lat)


@njit(cache=True)
def _rotate_attitude(q, dth0, dth1, dth2):
    """q ← exp(δθ) ⊗ q (NED-frame attitude correction) for the quaternion array q (4,)."""
    h0, h1, h2, h3 = rotvec_quat(dth0, dth1, dth2)
    n0, n1, n2, n3 = quat_mul(h0, h1, h2, h3, q[0], q[1], q[2], q[3])
    q[0], q[1], q[2], q[3] = normalised(n0, n1, n2, n3)


@njit(cache=True)
def _symmetrise(P):
    for i in range(N_ERR):
        for j in range(i + 1, N_ERR):
            a = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = a
            P[j, i] = a


@njit(cache=True)
def _apply_correction(x, par, dx):
    """Fold the error state into the nominal state (closed-loop feedback); the caller zeroes dx."""
    _rotate_attitude(x.q, dx[0], dx[1], dx[2])
    for i in range(3):
        x.vel_ned_m_s[i] += dx[E_V + i]
    lat = x.lat_rad
    r_n, r_e = _radii(par, lat)
    x.lat_rad = lat + dx[E_P] / (r_n + x.h_m)
    x.lon_rad += dx[E_P + 1] / ((r_e + x.h_m) * math.cos(lat))
    x.h_m -= dx[E_P + 2]
    gc = par.gyro_bias_clip_rad_s
    ac = par.accel_bias_clip_m_s2
    sc = par.gyro_scale_clip
    for i in range(3):
        x.gyro_bias_rad_s[i] = min(max(x.gyro_bias_rad_s[i] + dx[E_BG + i], -gc), gc)
        x.accel_bias_m_s2[i] = min(max(x.accel_bias_m_s2[i] + dx[E_BA + i], -ac), ac)
        x.gyro_scale[i] = min(max(x.gyro_scale[i] + dx[E_SG + i], -sc), sc)
    for i in range(6):
        x.gyro_misalignment_rad[i] = min(max(x.gyro_misalignment_rad[i] + dx[E_MG + i], -sc), sc)
    for i in range(N_MAG_HARMONICS):
        x.mag_heading_error_rad[i] += dx[E_MH + i]
    for i in range(N_MAG_FRAME_TILT):
        x.mag_frame_tilt_rad[i] += dx[E_MF + i]
    for i in range(N_ACC_Z_LEAN):
        x.accel_z_lean_rad[i] = min(max(x.accel_z_lean_rad[i] + dx[E_AZ_LEAN + i], -sc), sc)
    # the NED-frame low-passed specific force lives in the estimated NED frame: keep it there
    an = x.acc_ned_lp_m_s2[0]
    ae = x.acc_ned_lp_m_s2[1]
    ad = x.acc_ned_lp_m_s2[2]
    x.acc_ned_lp_m_s2[0] = an + dx[1] * ad - dx[2] * ae
    x.acc_ned_lp_m_s2[1] = ae + dx[2] * an - dx[0] * ad
    x.acc_ned_lp_m_s2[2] = ad + dx[0] * ae - dx[1] * an


@njit(cache=True)
def _gyro_matrix_corrected(x, ux, uy, uz):
    """(I − diag(s) − M) u: the bias-corrected rate u with the scale-factor and misalignment estimates removed
    (first order of (I + diag(s) + M)⁻¹, exact to < 1e-5 relative for |s|, |m| < 0.3 %)."""
    return (ux - x.gyro_scale[0] * ux - x.gyro_misalignment_rad[0] * uy - x.gyro_misalignment_rad[1] * uz,
            uy - x.gyro_scale[1] * uy - x.gyro_misalignment_rad[2] * ux - x.gyro_misalignment_rad[3] * uz,
            uz - x.gyro_scale[2] * uz - x.gyro_misalignment_rad[4] * ux - x.gyro_misalignment_rad[5] * uy)


@njit(cache=True)
def _accumulate_c_omega(x, c00, c01, c02, c10, c11, c12, c20, c21, c22, tx, ty, tz):
    """∫ C_ij ω_k dt += C_ij θ_k for the step's rotation increment θ = ω dt (Φ's scale/misalignment blocks)."""
    c = (c00, c01, c02, c10, c11, c12, c20, c21, c22)
    s = x.cov_c_omega_rad
    for ij in range(9):
        b = 3 * ij
        s[b] += c[ij] * tx
        s[b + 1] += c[ij] * ty
        s[b + 2] += c[ij] * tz


# ----------------------------------------------------------------------------------- covariance propagation
@njit(cache=True)
def transition_matrix(x, par):
    """Φ (N_ERR × N_ERR) of the interval accumulated since the last propagation (cov_t_s, the sums ∫C dt,
    ∫C ω dt, ΔV^n), as `propagate_covariance` applies it (3×3 blocks, order δθ, δv, δp, δb_g, δb_a, then δs_g,
    δm_g, then δm_a), with A = −∫C dt, B = −[ΔV^n×] and L = −∫C e_z [f_x, f_y] dt (the lean's):
        δθ: [I, 0, 0, A, 0, −∫C diag(ω) dt, −∫C W(ω) dt, 0];  δv: [B, I, 0, 0, A, 0, 0, L];
        δp: [½T B, T I, I, 0, ½T A, 0, 0, ½T L];  biases, scale factors, misalignments, lean: identity.
    The offline smoother (ins_smoother.py) reads it too."""
    T = x.cov_t_s
    phi = np.eye(N_ERR)
    for i in range(3):
        for j in range(3):
            phi[E_TH + i, E_SG + j] = -x.cov_c_omega_rad[9 * i + 4 * j]   # δθ̇ = −C diag(ω) δs: ∫ C_ij ω_j
            a = -x.cov_c_s[3 * i + j]
            phi[E_TH + i, E_BG + j] = a
            phi[E_V + i, E_BA + j] = a
            phi[E_P + i, E_BA + j] = 0.5 * T * a
        for n in range(6):   # δθ̇ = −C W(ω) δm: δm_jk moves ω_j by δm_jk ω_k
            phi[E_TH + i, E_MG + n] = -x.cov_c_omega_rad[9 * i + 3 * MIS_ROW[n] + MIS_COL[n]]
        for k in range(N_ACC_Z_LEAN):   # δv̇ = −C e_z f_k δm_zk: the lean moves the z axis's reading by m_zk f_k
            lean = -x.cov_c_f_m_s[2 * i + k]
            phi[E_V + i, E_AZ_LEAN + k] = lean
            phi[E_P + i, E_AZ_LEAN + k] = 0.5 * T * lean
    dvn = x.cov_dv_m_s[0]
    dve = x.cov_dv_m_s[1]
    dvd = x.cov_dv_m_s[2]
    # B = −[ΔV×]
    b = ((0.0, dvd, -dve), (-dvd, 0.0, dvn), (dve, -dvn, 0.0))
    for i in range(3):
        phi[E_P + i, E_V + i] = T
        for j in range(3):
            phi[E_V + i, E_TH + j] = b[i][j]
            phi[E_P + i, E_TH + j] = 0.5 * T * b[i][j]
    return phi


@njit(cache=True)
def _phi_p_phi_t(phi, P):
    """P ← Φ P Φᵀ in place, skipping Φ's zeros (most of it: `transition_matrix`): M = Φ P, then P = M Φᵀ."""
    m = np.zeros((N_ERR, N_ERR))
    for i in range(N_ERR):
        for k in range(N_ERR):
            a = phi[i, k]
            if a != 0.0:
                for j in range(N_ERR):
                    m[i, j] += a * P[k, j]
    for i in range(N_ERR):
        for j in range(N_ERR):
            P[i, j] = 0.0
    for j in range(N_ERR):
        for k in range(N_ERR):
            a = phi[j, k]
            if a != 0.0:
                for i in range(N_ERR):
                    P[i, j] += m[i, k] * a


@njit(cache=True)
def _add_process_noise(P, par, T):
    """P += Q over T s: white gyro and accelerometer noise and the bias, scale-factor and misalignment random
    walks, density² · T on the diagonal (isotropic, so rotating it by C changes nothing); the accelerometer's
    noise integrated twice into the position (T³/3) and its velocity–position correlation (T²/2)."""
    qg = par.gyro_noise_rad_s_sqrt_hz ** 2 * T
    qa = par.accel_noise_m_s2_sqrt_hz ** 2 * T
    qbg = par.gyro_bias_walk_rad_s_sqrt_s ** 2 * T
    qba = par.accel_bias_walk_m_s2_sqrt_s ** 2 * T
    for i in range(3):
        P[E_TH + i, E_TH + i] += qg
        P[E_V + i, E_V + i] += qa
        P[E_P + i, E_P + i] += qa * T * T / 3.0
        P[E_P + i, E_V + i] += 0.5 * qa * T
        P[E_V + i, E_P + i] += 0.5 * qa * T
        P[E_BG + i, E_BG + i] += qbg
        P[E_BA + i, E_BA + i] += qba
        P[E_SG + i, E_SG + i] += par.gyro_scale_walk_sqrt_s ** 2 * T
        P[E_MG + i, E_MG + i] += par.gyro_misalignment_walk_rad_sqrt_s ** 2 * T
        P[E_MG + 3 + i, E_MG + 3 + i] += par.gyro_misalignment_walk_rad_sqrt_s ** 2 * T
    if par.mag_harmonics_on > 0.0:
        for i in range(N_MAG_HARMONICS):
            P[E_MH + i, E_MH + i] += par.mag_harmonic_walk_rad_sqrt_s ** 2 * T


@njit(cache=True)
def _clear_increments(x):
    """Start the next covariance interval: the time and the sums ∫C dt, ∫C ω dt, ΔV^n back to zero."""
    x.cov_t_s = 0.0
    for i in range(9):
        x.cov_c_s[i] = 0.0
    for i in range(27):
        x.cov_c_omega_rad[i] = 0.0
    for i in range(6):
        x.cov_c_f_m_s[i] = 0.0
    for i in range(3):
        x.cov_dv_m_s[i] = 0.0


@njit(cache=True)
def propagate_covariance(x, P, par):
    """P ← Φ P Φᵀ + Q over the time accumulated since the last call (cov_t_s), then clear the sums.

    Φ: `transition_matrix`; the product `_phi_p_phi_t`; Q: `_add_process_noise`."""
    T = x.cov_t_s
    if T <= 0.0:
        return
    _phi_p_phi_t(transition_matrix(x, par), P)
    _add_process_noise(P, par, T)
    _symmetrise(P)
    _clear_increments(x)


# ----------------------------------------------------------------------------------- the per-sample step
@njit(cache=True)
def _aided(x, par):
    """Velocity/position known and a fix fused less than dead_reckon_s ago: the accelerometer is left to the
    mechanisation (no levelling)."""
    return x.nav_ok > 0.0 and x.t_last_s - x.gnss_fused_t_s < par.dead_reckon_s


@njit(cache=True)
def _level(x, P, par, dt_epoch):
    """Accelerometer levelling (tilt only) from the NED-frame low-passed specific force, with mekf's gating:
    off while | |f_lp| − g | > level_reject_m_s2 or the low-passed vertical is more than level_gate_rad from the
    estimate, then held off for 4 τ (until the low-pass has forgotten the push), unless nothing was accepted
    for level_recover_s. Tilt only: heading, gyro and accelerometer biases get no gain — the levelled vertical
    leans into any sustained acceleration (a boat's turn, a/g), an error that is not white noise, and learnt
    into the biases it would survive the return of GNSS (which then reads the lean as a bias). Returns
    F_ACCEL_REJECTED or 0."""
    un = x.acc_ned_lp_m_s2[0]
    ue = x.acc_ned_lp_m_s2[1]
    ud = x.acc_ned_lp_m_s2[2]
    unorm = math.sqrt(un * un + ue * ue + ud * ud)
    g = normal_gravity_m_s2(x.lat_rad, x.h_m) if x.nav_ok > 0.0 else 9.80665
    if unorm <= 0.5 * g:
        x.acc_since_accept_s += dt_epoch
        return F_ACCEL_REJECTED
    nu_n = un / unorm     # = δθ_E (+ noise): the measured "up" is [δθ_E, −δθ_N, −1]
    nu_e = ue / unorm     # = −δθ_N
    tau = par.level_lowpass_tau_s
    if abs(unorm - g) > par.level_reject_m_s2 or nu_n * nu_n + nu_e * nu_e > par.level_gate_rad ** 2:
        x.acc_hold_s = 4.0 * tau
    elif x.acc_hold_s > 0.0:
        x.acc_hold_s -= dt_epoch
    if x.acc_hold_s > 0.0 and x.acc_since_accept_s <= par.level_recover_s:
        x.acc_since_accept_s += dt_epoch
        return F_ACCEL_REJECTED
    r = (par.level_noise_m_s2 / g) ** 2
    # the lean this update carries into the tilt in a turn, for the published 1σ (turn_lean.py)
    track_tilt_push(x.turn_lean, par.turn_speed_m_s, g, levelling_gain(P[E_TILT_E, E_TILT_E], r))
    mask = (M_HEADING | M_ACC_BIAS | M_GYRO_BIAS | M_GYRO_SCALE | M_GYRO_MIS | M_MAG_HARMONICS
            | M_MAG_FRAME_TILT | M_ACC_Z_LEAN)   # tilt only
    dx = np.zeros(N_ERR)
    h = np.zeros(N_ERR)
    h[1] = 1.0
    scalar_update(P, h, nu_n, r, mask, dx)
    h[1] = 0.0
    h[0] = -1.0
    scalar_update(P, h, residual(h, nu_e, dx), r, mask, dx)
    _apply_correction(x, par, dx)
    x.acc_since_accept_s = 0.0
    return 0


@njit(cache=True)
def _iron_corrected(par, mx, my, mz):
    """The magnetometer sample in the body frame with the learned iron removed: the hard iron subtracted, then
    the soft iron's inverse (I + D)⁻¹ applied, µT."""
    hx = mx - par.iron_ut[0]
    hy = my - par.iron_ut[1]
    hz = mz - par.iron_ut[2]
    a = par.iron_soft_inv
    return (a[0, 0] * hx + a[0, 1] * hy + a[0, 2] * hz,
            a[1, 0] * hx + a[1, 1] * hy + a[1, 2] * hz,
            a[2, 0] * hx + a[2, 1] * hy + a[2, 2] * hz)


@njit(cache=True)
def _gnss_holds_tilt(x, par):
    """A fix was fused within gnss_timeout_s: the GNSS velocity holds the horizon (GNSS_AIDED)."""
    return x.nav_ok > 0.0 and x.t_last_s - x.gnss_fused_t_s <= par.gnss_timeout_s


@njit(cache=True)
def _mag_heading_row(x, par, mn, me, md):
    """The heading measurement's row h (N_ERR) for the field (mn, me, md) in the estimated NED frame, and whether
    its update may move the tilt.

    The heading of the horizontal field depends on the tilt too: with m = H u + Z e_D (u the magnetic north),
    m_est = m − δθ × m gives α = −δθ_D + (Z/H) u·δθ, so a tilt error along magnetic north reads as tan(dip)
    times as much heading error (3.4× at 60° N). While fixes hold the horizon (GNSS_AIDED) the row carries that
    sensitivity, so the heading correction allows for the known tilt error through their covariance; the gain
    on the tilt itself is zero (a wrong magnetometer must never move the horizon) unless mag_moves_tilt.
    Otherwise — before the first fix, dead reckoning, levelling — the row is heading only, as in mekf."""
    h = np.zeros(N_ERR)
    h[2] = -1.0
    aided = _gnss_holds_tilt(x, par)
    moves_tilt = aided and par.mag_moves_tilt > 0.0
    mh2 = mn * mn + me * me
    if aided and mh2 > 0.0:
        h[0] = md * mn / mh2
        h[1] = md * me / mh2
    return h, moves_tilt


@njit(cache=True)
def _attitude_variance(P, h):
    """h P hᵀ over the attitude block (the heading row has no other entries)."""
    hph = 0.0
    for i in range(3):
        for j in range(3):
            hph += h[i] * P[i, j] * h[j]
    return hph


@njit(cache=True)
def _magnetic_heading_rad(x, par):
    """The vehicle's estimated magnetic heading (body x about down from magnetic north), rad: what the
    calibration's heading error is a function of (mag_harmonics.py)."""
    q0, q1, q2, q3 = x.q[0], x.q[1], x.q[2], x.q[3]
    return math.atan2(2.0 * (q0 * q3 + q1 * q2), 1.0 - 2.0 * (q2 * q2 + q3 * q3)) - par.declination_rad


@njit(cache=True)
def _add_harmonics_to_row(x, par, h):
    """With the harmonic states on: their entries in the heading row h (the basis at the magnetic heading), and
    the field azimuth they predict (rad, subtracted from the measured one); 0 otherwise."""
    if par.mag_harmonics_on <= 0.0:
        return 0.0
    psi = _magnetic_heading_rad(x, par)
    b0, b1, b2, b3, b4 = harmonic_basis(psi)
    h[E_MH] = b0
    h[E_MH + 1] = b1
    h[E_MH + 2] = b2
    h[E_MH + 3] = b3
    h[E_MH + 4] = b4
    return heading_error_rad(x.mag_heading_error_rad, psi)


@njit(cache=True)
def _harmonic_row_variance(P, h):
    """h P hᵀ over the harmonic states and their covariance with the attitude (the rest of the heading row's
    h P hᵀ, `_attitude_variance` having the attitude block)."""
    v = 0.0
    for i in range(N_MAG_HARMONICS):
        hi = h[E_MH + i]
        for j in range(N_MAG_HARMONICS):
            v += hi * P[E_MH + i, E_MH + j] * h[E_MH + j]
        for j in range(3):
            v += 2.0 * hi * P[E_MH + i, E_TH + j] * h[E_TH + j]
    return v


@njit(cache=True)
def _add_frame_tilt_to_row(x, par, h):
    """With the frame-tilt states on: their entries in the heading row h (`frame_tilt_partials` of the row's
    entries on the attitude, which must be in h already), and the field azimuth the estimated tilt turns (rad,
    subtracted from the measured one); 0 otherwise."""
    if par.mag_frame_tilt_on <= 0.0:
        return 0.0
    dx_, dy_ = frame_tilt_partials(h[E_TH], h[E_TH + 1], h[E_TH + 2], dcm(x.q[0], x.q[1], x.q[2], x.q[3]))
    h[E_MF] = dx_
    h[E_MF + 1] = dy_
    return dx_ * x.mag_frame_tilt_rad[0] + dy_ * x.mag_frame_tilt_rad[1]


@njit(cache=True)
def _frame_tilt_row_variance(P, h):
    """h P hᵀ's part that involves the frame-tilt states F, the other entries of h being those of
    `_attitude_variance` and `_harmonic_row_variance`: Σ_{i∈F} h_i (2 (P h)_i − Σ_{j∈F} P_ij h_j), their block
    once and their covariance with every other entry twice."""
    v = 0.0
    for i in range(E_MF, E_MF + N_MAG_FRAME_TILT):
        whole = 0.0
        for j in range(N_ERR):
            whole += P[i, j] * h[j]
        own = P[i, E_MF] * h[E_MF] + P[i, E_MF + 1] * h[E_MF + 1]
        v += h[i] * (2.0 * whole - own)
    return v


@njit(cache=True)
def _heading_error_var(par):
    """The heading error's variance the update treats as slowly varying noise (inflated by τ/Δt): the whole
    calibration's without the harmonic states, only what they leave with them."""
    return par.mag_harmonic_residual_var_rad2 if par.mag_harmonics_on > 0.0 else par.mag_bias_var_rad2


@njit(cache=True)
def _fuse_mag_heading(x, P, par, dt_epoch, h, alpha, r, moves_tilt):
    """The heading update (innovation alpha, row h, noise r from mag_heading.py) into the state, its gain on the
    tilt zero unless `moves_tilt`.

    The calibration's error is not white: a heading bias of variance mag_bias_var_rad2 that lasts about
    mag_bias_tau_s. Fused every Δt as if white it would shrink the heading σ below it; spread over the τ/Δt
    updates of one correlation time it adds at most its own variance's worth of information."""
    r += _heading_error_var(par) * max(1.0, par.mag_bias_tau_s / max(dt_epoch, 1e-6))
    if not _aided(x, par):
        # levelled: the tilt's turn lean becomes heading error through the dip (turn_lean.py)
        track_heading_push(x.turn_lean, x.mag.ref_dip_rad, P[E_YAW, E_YAW], r)
    held = 0 if moves_tilt else M_TILT
    if not _gnss_holds_tilt(x, par):
        # the harmonic states (and the frame tilt) learn only while the GNSS holds the tilt: levelled in turns, the tilt leans towards
        # the turn's centre, a lean that turns with the heading and so, through the dip, reads as a once-per-turn
        # heading error the states would take for the calibration's (they still count in the innovation's variance)
        held |= M_MAG_HARMONICS | M_MAG_FRAME_TILT
    dx = np.zeros(N_ERR)
    scalar_update(P, h, alpha, r, held, dx)
    _apply_correction(x, par, dx)


@njit(cache=True)
def _mag_update(x, P, par, dt_epoch, rate):
    """Magnetometer heading update (the shared check of mag_heading.py, `_fuse_mag_heading` when it passes):
    returns flag bits."""
    ms = x.mag
    mp = par.mag
    flags = 0
    used = False
    mx = x.mag_last_ut[0]
    my = x.mag_last_ut[1]
    mz = x.mag_last_ut[2]
    if par.mag_enabled > 0.0 and par.mag_use > 0.0 and math.isfinite(mx):
        mx, my, mz = _iron_corrected(par, mx, my, mz)
        mn, me, md = rotate_to_ned(x.q[0], x.q[1], x.q[2], x.q[3], mx, my, mz)
        mnorm = math.sqrt(mx * mx + my * my + mz * mz)
        h, moves_tilt = _mag_heading_row(x, par, mn, me, md)
        predicted_error = _add_harmonics_to_row(x, par, h)
        heading_var = _attitude_variance(P, h) + _harmonic_row_variance(P, h) + _heading_error_var(par)
        if par.mag_frame_tilt_on > 0.0:
            predicted_error += _add_frame_tilt_to_row(x, par, h)
            heading_var += _frame_tilt_row_variance(P, h)
        res, alpha, r = mag.heading_measurement(ms, mp, dt_epoch, rate, False, False, mn, me, md, mnorm,
                                                par.declination_rad + predicted_error, heading_var)
        if res == mag.MAG_USE:
            _fuse_mag_heading(x, P, par, dt_epoch, h, alpha, r, moves_tilt)
            used = True
        elif res == mag.MAG_REJECTED:
            flags |= F_MAG_REJECTED
    elif par.mag_enabled > 0.0 and math.isfinite(mx):
        flags |= F_MAG_REJECTED     # the heading monitor rejects it (disagrees with GNSS or its own innovations)
    if mag.heading_bookkeeping(ms, mp, dt_epoch, used):
        flags |= F_MAG_UNAVAILABLE
    return flags


@njit(cache=True)
def _take_sample(x, valid, gx, gy, gz, ax, ay, az, mx, my, mz):
    """Keep this sample's valid sensors as the last ones; return the bias- (and scale-, misalignment-)
    corrected rate of this sample (wx, wy, wz), and the rate (mwx, mwy, mwz) and specific force (fx, fy, fz)
    over the step. The samples are instantaneous values at their times: over the step use the mean of the
    previous and this one (trapezoid; the last sample alone lags by half a step: ½ Δt · Δω of heading per
    change of rate)."""
    pgx = x.gyro_last_rad_s[0]
    pgy = x.gyro_last_rad_s[1]
    pgz = x.gyro_last_rad_s[2]
    pax = x.acc_last_m_s2[0]
    pay = x.acc_last_m_s2[1]
    paz = x.acc_last_m_s2[2]
    if valid & IN_GYRO_OK:
        x.gyro_last_rad_s[0] = gx
        x.gyro_last_rad_s[1] = gy
        x.gyro_last_rad_s[2] = gz
    if valid & IN_ACC_OK:
        x.acc_last_m_s2[0] = ax
        x.acc_last_m_s2[1] = ay
        x.acc_last_m_s2[2] = az
    if valid & IN_MAG_OK:
        x.mag_last_ut[0] = mx
        x.mag_last_ut[1] = my
        x.mag_last_ut[2] = mz
    wx = x.gyro_last_rad_s[0] - x.gyro_bias_rad_s[0]
    wy = x.gyro_last_rad_s[1] - x.gyro_bias_rad_s[1]
    wz = x.gyro_last_rad_s[2] - x.gyro_bias_rad_s[2]
    mwx = 0.5 * (pgx + x.gyro_last_rad_s[0]) - x.gyro_bias_rad_s[0]
    mwy = 0.5 * (pgy + x.gyro_last_rad_s[1]) - x.gyro_bias_rad_s[1]
    mwz = 0.5 * (pgz + x.gyro_last_rad_s[2]) - x.gyro_bias_rad_s[2]
    # scale factor and misalignment: ω = (I + diag(s) + M)⁻¹ (ω_meas − b) ≈ (I − diag(s) − M)(ω_meas − b)
    wx, wy, wz = _gyro_matrix_corrected(x, wx, wy, wz)
    mwx, mwy, mwz = _gyro_matrix_corrected(x, mwx, mwy, mwz)
    fx = 0.5 * (pax + x.acc_last_m_s2[0]) - x.accel_bias_m_s2[0]
    fy = 0.5 * (pay + x.acc_last_m_s2[1]) - x.accel_bias_m_s2[1]
    fz = 0.5 * (paz + x.acc_last_m_s2[2]) - x.accel_bias_m_s2[2]
    # the z axis's lean: f_z,meas = f_z + m_zx f_x + m_zy f_y (first order in M_a, as the gyro's above)
    fz -= x.accel_z_lean_rad[0] * fx + x.accel_z_lean_rad[1] * fy
    return wx, wy, wz, mwx, mwy, mwz, fx, fy, fz


@njit(cache=True)
def _navigation_known(x, par):
    """Velocity and position set by a fix and not dropped: so long without a fix (nav_drop_s) that they mean
    nothing, they are no longer integrated (the next fix sets them again, as the first one did)."""
    if x.nav_ok > 0.0 and x.t_last_s - x.gnss_fused_t_s > par.nav_drop_s:
        x.nav_ok = 0.0
        for i in range(3):
            x.vel_ned_m_s[i] = 0.0
    return x.nav_ok > 0.0


@njit(cache=True, inline="always")
def _rate_relative_to_ned(x, c, earth, r_n, r_e, mwx, mwy, mwz):
    """The body rate relative to NED, ω_nb = ω_ib − C_n^b (ω_ie + ω_en) (Groves eq. 5.77; `c`: C_b^n as `dcm`'s
    9-tuple): the Earth rate and the transport rate only when `earth` (they need the latitude)."""
    rx, ry, rz = mwx, mwy, mwz
    if earth:
        c00, c01, c02, c10, c11, c12, c20, c21, c22 = c
        lat = x.lat_rad
        en, ee, ed = earth_rate_ned(lat)
        tn, te, td = transport_rate_ned(lat, x.h_m, x.vel_ned_m_s[0], x.vel_ned_m_s[1], r_n, r_e)
        sn = en + tn
        se = ee + te
        sd = ed + td
        rx -= c00 * sn + c10 * se + c20 * sd
        ry -= c01 * sn + c11 * se + c21 * sd
        rz -= c02 * sn + c12 * se + c22 * sd
    return rx, ry, rz


@njit(cache=True, inline="always")
def _mid_step_specific_force_ned(c, thx, thy, thz, fx, fy, fz):
    """The specific force at the middle of the step in NED: f + ½ θ × f in the body frame at the start (θ: the
    step's rotation), rotated by C_b^n at the start (`c`)."""
    c00, c01, c02, c10, c11, c12, c20, c21, c22 = c
    mfx = fx + 0.5 * (thy * fz - thz * fy)
    mfy = fy + 0.5 * (thz * fx - thx * fz)
    mfz = fz + 0.5 * (thx * fy - thy * fx)
    return (c00 * mfx + c01 * mfy + c02 * mfz,
            c10 * mfx + c11 * mfy + c12 * mfz,
            c20 * mfx + c21 * mfy + c22 * mfz)


@njit(cache=True, inline="always")
def _strapdown_attitude(x, thx, thy, thz):
    """C_b^n ← C_b^n exp(ω_nb dt) (eq. 20) as q ← q ⊗ q(θ), normalised; returns the new q."""
    e0, e1, e2, e3 = rotvec_quat(thx, thy, thz)
    n0, n1, n2, n3 = quat_mul(x.q[0], x.q[1], x.q[2], x.q[3], e0, e1, e2, e3)
    q0, q1, q2, q3 = normalised(n0, n1, n2, n3)
    x.q[0] = q0
    x.q[1] = q1
    x.q[2] = q2
    x.q[3] = q3
    return q0, q1, q2, q3


@njit(cache=True, inline="always")
def _integrate_navigation(x, dt, fn, fe, fd, r_n, r_e, earth):
    """Velocity (eq. 14, from the mid-step specific force in NED) and position (eq. 17, trapezoid in the
    velocity) over Δt; returns the new velocity."""
    lat = x.lat_rad
    h_m = x.h_m
    vn = x.vel_ned_m_s[0]
    ve = x.vel_ned_m_s[1]
    vd = x.vel_ned_m_s[2]
    an, ae, ad = velocity_rate_ned(fn, fe, fd, vn, ve, vd, lat, h_m, r_n, r_e, earth)
    nvn = vn + an * dt
    nve = ve + ae * dt
    nvd = vd + ad * dt
    ldot, odot, hdot = position_rates(lat, h_m, 0.5 * (vn + nvn), 0.5 * (ve + nve), 0.5 * (vd + nvd), r_n, r_e)
    x.vel_ned_m_s[0] = nvn
    x.vel_ned_m_s[1] = nve
    x.vel_ned_m_s[2] = nvd
    x.lat_rad = lat + ldot * dt
    x.lon_rad += odot * dt
    x.h_m = h_m + hdot * dt
    return nvn, nve, nvd


@njit(cache=True, inline="always")
def _accumulate_increments(x, par, dt, c, fn, fe, fd, mwx, mwy, mwz, fx, fy):
    """What the covariance epoch and the levelling take from each step: the interval, ∫C dt, ΔV^n = ∫f^n dt,
    ∫C_ij ω_k dt and ∫C_iz f_k dt (body f_x, f_y: the lean's) (`propagate_covariance`'s transition matrix), and the
    NED-frame low-pass of the specific force (levelling: linear acceleration averages out, gravity stays)."""
    c00, c01, c02, c10, c11, c12, c20, c21, c22 = c
    x.cov_t_s += dt
    x.cov_c_s[0] += c00 * dt
    x.cov_c_s[1] += c01 * dt
    x.cov_c_s[2] += c02 * dt
    x.cov_c_s[3] += c10 * dt
    x.cov_c_s[4] += c11 * dt
    x.cov_c_s[5] += c12 * dt
    x.cov_c_s[6] += c20 * dt
    x.cov_c_s[7] += c21 * dt
    x.cov_c_s[8] += c22 * dt
    x.cov_dv_m_s[0] += fn * dt
    x.cov_dv_m_s[1] += fe * dt
    x.cov_dv_m_s[2] += fd * dt
    _accumulate_c_omega(x, c00, c01, c02, c10, c11, c12, c20, c21, c22, mwx * dt, mwy * dt, mwz * dt)
    s = x.cov_c_f_m_s
    s[0] += c02 * fx * dt
    s[1] += c02 * fy * dt
    s[2] += c12 * fx * dt
    s[3] += c12 * fy * dt
    s[4] += c22 * fx * dt
    s[5] += c22 * fy * dt
    tau = par.level_lowpass_tau_s
    k = 1.0 - math.exp(-dt / tau) if tau > 0.0 else 1.0
    x.acc_ned_lp_m_s2[0] += k * (fn - x.acc_ned_lp_m_s2[0])
    x.acc_ned_lp_m_s2[1] += k * (fe - x.acc_ned_lp_m_s2[1])
    x.acc_ned_lp_m_s2[2] += k * (fd - x.acc_ned_lp_m_s2[2])


@njit(cache=True)
def _mechanise(x, par, dt, nav_ok, mwx, mwy, mwz, fx, fy, fz):
    """NED strapdown over Δt (P. D. Groves, Principles of GNSS, Inertial, and Multisensor Integrated
    Navigation Systems, 2nd ed., §5.4): attitude (`_rate_relative_to_ned`, `_strapdown_attitude`), then velocity
    and position (`_integrate_navigation`; held before the first fix) from the mid-step specific force
    (`_mid_step_specific_force_ned`); accumulates the covariance increments and the NED-frame low-pass of the
    specific force (`_accumulate_increments`). Returns the new attitude and velocity."""
    c = dcm(x.q[0], x.q[1], x.q[2], x.q[3])
    r_n, r_e = _radii(par, x.lat_rad)
    earth = par.earth_rotation > 0.0 and nav_ok   # the Earth rate needs the latitude
    rx, ry, rz = _rate_relative_to_ned(x, c, earth, r_n, r_e, mwx, mwy, mwz)
    thx = rx * dt
    thy = ry * dt
    thz = rz * dt
    fn, fe, fd = _mid_step_specific_force_ned(c, thx, thy, thz, fx, fy, fz)
    q0, q1, q2, q3 = _strapdown_attitude(x, thx, thy, thz)
    # before the first fix velocity and position are unknown and held
    vn = x.vel_ned_m_s[0]
    ve = x.vel_ned_m_s[1]
    vd = x.vel_ned_m_s[2]
    if nav_ok:
        vn, ve, vd = _integrate_navigation(x, dt, fn, fe, fd, r_n, r_e, earth)
    _accumulate_increments(x, par, dt, c, fn, fe, fd, mwx, mwy, mwz, fx, fy)
    return q0, q1, q2, q3, vn, ve, vd


@njit(cache=True)
def _record_history(x, hist, t_s, q0, q1, q2, q3, vn, ve, vd, wx, wy, wz):
    """A history row for fusing late fixes at their time of validity."""
    i = (int(x.hist_newest) + 1) % H_LEN
    x.hist_newest = i
    x.hist_count = min(x.hist_count + 1.0, float(H_LEN))
    row = hist[i]
    row.t_s = t_s
    row.q[0] = q0
    row.q[1] = q1
    row.q[2] = q2
    row.q[3] = q3
    row.vel_ned_m_s[0] = vn
    row.vel_ned_m_s[1] = ve
    row.vel_ned_m_s[2] = vd
    row.lat_rad = x.lat_rad
    row.lon_rad = x.lon_rad
    row.h_m = x.h_m
    row.rate_rad_s[0] = wx
    row.rate_rad_s[1] = wy
    row.rate_rad_s[2] = wz


@njit(cache=True)
def _lowpass_rate_down(x, par, epoch_s):
    """The rate about the vertical over the epoch, low-passed as the levelling's specific force is (τ =
    level_lowpass_tau_s), for the lean a turn leaves (turn_lean.py). The epoch's mean ω_D = Σ_j ∫C_Dj ω_j dt /
    Δt is already summed for the covariance (`_accumulate_c_omega`: index 9 i + 3 j + k, i = D = 2, k = j)."""
    if epoch_s <= 0.0:
        return
    s = x.cov_c_omega_rad
    tau = par.level_lowpass_tau_s
    k = 1.0 - math.exp(-epoch_s / tau) if tau > 0.0 else 1.0
    lowpass_rate_down(x.turn_lean, k, (s[18] + s[22] + s[26]) / epoch_s)


@njit(cache=True)
def _covariance_epoch(x, P, par, nav_ok, rate):
    """Every cov_period_s: propagate the covariance, then the levelling (while unaided) and the magnetometer
    heading update. Returns flag bits."""
    flags = 0
    epoch = x.cov_t_s
    levelling = not _aided(x, par)
    if levelling:
        _lowpass_rate_down(x, par, epoch)    # reads the epoch's sums: before the propagation clears them
    propagate_covariance(x, P, par)
    if not nav_ok:
        # unknown velocity/position: keep their block bounded and uncorrelated until a fix sets them
        _reset_block(P, np.int64(E_V), np.full(3, NAV_UNKNOWN_VAR_V))    # np.int64: one compile for every block
        _reset_block(P, np.int64(E_P), np.full(3, NAV_UNKNOWN_VAR_P))
    if levelling:
        flags |= _level(x, P, par, epoch)
    else:
        clear(x.turn_lean)    # the GNSS velocity observes the lean: no turn-lean terms while aided
    flags |= _mag_update(x, P, par, epoch, rate)
    _symmetrise(P)
    return flags


@njit(cache=True, inline="always")
def _feed_gnss_yaw_bank(x, gsf, gsf_par, dt, mwx, mwy, mwz, fx, fy, fz):
    """The sample for the GNSS yaw bank (gsf_yaw.py): this filter's corrected rate over the step with the bank's
    gyro bias in place of the filter's (to first order: the scale and misalignment terms of the bias difference
    are second order), and the specific force."""
    bgx = x.gyro_bias_rad_s[0] - x.bank_gyro_bias_rad_s[0]
    bgy = x.gyro_bias_rad_s[1] - x.bank_gyro_bias_rad_s[1]
    bgz = x.gyro_bias_rad_s[2] - x.bank_gyro_bias_rad_s[2]
    gsf_accumulate_imu_xyz(gsf[0], gsf_par[0], dt, mwx + bgx, mwy + bgy, mwz + bgz, fx, fy, fz)


@njit(cache=True, inline="always")
def _status_flags(x, par, sigma_rpy_rad):
    """GNSS_AIDED or GNSS_OUTAGE (once a fix has been fused), and INITIALISING while the filter has not run
    init_min_time_s or its 1σ (`sigma_rpy_rad`, before the turn-lean terms) is above the converged limits."""
    flags = 0
    if x.was_aided > 0.0:
        if x.t_last_s - x.gnss_fused_t_s <= par.gnss_timeout_s:
            flags |= F_GNSS_AIDED
        else:
            flags |= F_GNSS_OUTAGE
    if initialising(x.t_run_s, sigma_rpy_rad[0], sigma_rpy_rad[1], sigma_rpy_rad[2], par.init_min_time_s,
                    par.converged_tilt_rad, par.mag_enabled > 0.0, par.converged_yaw_rad):
        flags |= F_INITIALISING
    return flags


@njit(cache=True, inline="always")
def _sum_gyro_rotation(x, t_s, gx, gy, gz):
    """The gyro's raw rotation since the last heading check, for Ins._mag_rotation_check (mag_rotation.py):
    here rather than in Python per sample for speed; a gap of 0.1 s or more is not summed."""
    dt_rotation = t_s - x.gyro_rotation_last_t_s
    x.gyro_rotation_last_t_s = t_s
    if 0.0 < dt_rotation < 0.1:
        rotation_vector_step(x.gyro_rotation_rad, gx, gy, gz, dt_rotation)
        x.gyro_rotation_s += dt_rotation


@njit(cache=True)
def ins_step(state, P, hist, params, t_s, gx, gy, gz, ax, ay, az, mx, my, mz, sample_flags, out, gsf, gsf_par):
    """One IMU sample through the stages: take the sample, mechanise (`_mechanise`) and record the history,
    every cov_period_s the covariance epoch (`_covariance_epoch`: propagation, levelling when unaided,
    magnetometer heading); feed the magnetometer-free GNSS yaw bank (`gsf`, `gsf_par`: 1-element record
    arrays of gsf_yaw.py's state and parameters; its own tilt and yaw, never this filter's heading) the
    corrected sample; fill `out`. state, params, out: 1-element INS_STATE_DTYPE, INS_PARAMS_DTYPE and
    INS_OUT_DTYPE arrays; hist: the INS_HISTORY_DTYPE ring. Returns EstimateFlags bits (| NEEDS_INIT when the
    caller must initialise from this sample first)."""
    x = state[0]
    par = params[0]
    o = out[0]
    valid = input_validity(sample_flags, gx, gy, gz, ax, ay, az, mx, my, mz)
    dt, flags = step_dt(t_s - x.t_last_s, par.large_dt_s, par.reinit_dt_s)
    if flags & NEEDS_INIT:
        return flags
    if dt > 0.0:
        x.t_last_s = t_s
    x.t_run_s += dt
    wx, wy, wz, mwx, mwy, mwz, fx, fy, fz = _take_sample(x, valid, gx, gy, gz, ax, ay, az, mx, my, mz)
    if par.gnss_yaw > 0.0:
        _feed_gnss_yaw_bank(x, gsf, gsf_par, dt, mwx, mwy, mwz, fx, fy, fz)
    nav_ok = _navigation_known(x, par)
    if dt > 0.0:
        q0, q1, q2, q3, vn, ve, vd = _mechanise(x, par, dt, nav_ok, mwx, mwy, mwz, fx, fy, fz)
        _record_history(x, hist, t_s, q0, q1, q2, q3, vn, ve, vd, wx, wy, wz)
    if x.cov_t_s >= par.cov_period_s:
        flags |= _covariance_epoch(x, P, par, nav_ok, math.sqrt(wx * wx + wy * wy + wz * wz))
    fill_outputs(x, P, par, wx, wy, wz, o)
    flags |= _status_flags(x, par, o.sigma_rpy_rad)
    # after the convergence test (the filter converges on its covariance, not on a turn's lean, as mekf):
    # the published 1σ adds the lean levelling has left in a turn (turn_lean.py; zero while aided)
    add_pushes_to_sigma(x.turn_lean, o.sigma_rpy_rad)
    _sum_gyro_rotation(x, t_s, gx, gy, gz)
    return flags


@njit(cache=True)
def fill_outputs(x, P, par, wx, wy, wz, out):
    """The step's outputs from the state `x` and covariance `P` into `out`, an INS_OUT_DTYPE record (wx, wy,
    wz: the bias-corrected rate)."""
    q0 = x.q[0]
    q1 = x.q[1]
    q2 = x.q[2]
    q3 = x.q[3]
    # magnetic-north frame for the estimate: q_mag = q_z(−declination) ⊗ q_true
    hd = -0.5 * par.declination_rad
    m0, m1, m2, m3 = quat_mul(math.cos(hd), 0.0, 0.0, math.sin(hd), q0, q1, q2, q3)
    if m0 < 0.0:
        m0, m1, m2, m3 = -m0, -m1, -m2, -m3
    out.q[0] = m0
    out.q[1] = m1
    out.q[2] = m2
    out.q[3] = m3
    out.rate_rad_s[0] = wx
    out.rate_rad_s[1] = wy
    out.rate_rad_s[2] = wz
    roll, pitch, yaw, sig_roll, sig_pitch = euler_and_tilt_sigma(q0, q1, q2, q3, P[E_TH, E_TH], P[E_TH, E_TH + 1],
                                                                  P[E_TH + 1, E_TH + 1])
    out.sigma_rpy_rad[0] = sig_roll
    out.sigma_rpy_rad[1] = sig_pitch
    out.sigma_rpy_rad[2] = math.sqrt(max(P[E_TH + 2, E_TH + 2], 0.0))
    out.euler_rad[0] = roll
    out.euler_rad[1] = pitch
    out.euler_rad[2] = yaw
    for i in range(3):
        out.gyro_bias_rad_s[i] = x.gyro_bias_rad_s[i]
        out.accel_bias_m_s2[i] = x.accel_bias_m_s2[i]
        out.vel_ned_m_s[i] = x.vel_ned_m_s[i]
        out.sigma_vel_m_s[i] = math.sqrt(max(P[E_V + i, E_V + i], 0.0))
        out.sigma_pos_m[i] = math.sqrt(max(P[E_P + i, E_P + i], 0.0))
    out.lat_rad = x.lat_rad
    out.lon_rad = x.lon_rad
    out.h_m = x.h_m


# ----------------------------------------------------------------------------------- GNSS fusion
@njit(cache=True)
def _history_at(x, hist, t):
    """Row index pair (older, newer) and weight w of the newer one bracketing time t; (−1, −1, 0) when t is
    older than the history. A t at or after the newest row returns that row."""
    return history_bracket(hist.t_s, int(x.hist_newest), int(x.hist_count), t)


@njit(cache=True)
def history_bracket(t_rows, newest, count, t):
    """`_history_at` on the ring's row times t_rows (a view of the history's `t_s`, or of its flat rows' time
    column: lever_arm_kernel.py) with `count` kept rows up to ring index `newest`, walked back from the newest row
    (the kept rows' times increase). history_rows.bracket is its Python twin, for Python callers."""
    if count == 0:
        return -1, -1, 0.0
    if t >= t_rows[newest]:
        return newest, newest, 1.0
    ring = t_rows.shape[0]
    i = newest
    for _ in range(count - 1):
        j = (i - 1) % ring
        tj = t_rows[j]
        if tj <= t:
            return j, i, (t - tj) / (t_rows[i] - tj)
        i = j
    return -1, -1, 0.0


@njit(cache=True)
def _lever_terms(q0, q1, q2, q3, wx, wy, wz, lx, ly, lz):
    """The antenna offset C r and its velocity C (ω × r) in NED, and C as 9 scalars."""
    c = dcm(q0, q1, q2, q3)
    on = c[0] * lx + c[1] * ly + c[2] * lz
    oe = c[3] * lx + c[4] * ly + c[5] * lz
    od = c[6] * lx + c[7] * ly + c[8] * lz
    cx = wy * lz - wz * ly
    cy = wz * lx - wx * lz
    cz = wx * ly - wy * lx
    un = c[0] * cx + c[1] * cy + c[2] * cz
    ue = c[3] * cx + c[4] * cy + c[5] * cz
    ud = c[6] * cx + c[7] * cy + c[8] * cz
    return on, oe, od, un, ue, ud, c


@njit(cache=True)
def _skew_rows(hrow, comp, an, ae, ad, scale):
    """Put row `comp` of −scale·[a×] into the δθ block of h."""
    if comp == 0:
        hrow[1] = scale * ad
        hrow[2] = -scale * ae
    elif comp == 1:
        hrow[0] = -scale * ad
        hrow[2] = scale * an
    else:
        hrow[0] = scale * ae
        hrow[1] = -scale * an


@njit(cache=True)
def _nis(P, H, nu, var, m):
    """νᵀ (H P Hᵀ + diag(var))⁻¹ ν for m ≤ 3 rows of H (Gauss–Jordan on the small innovation covariance)."""
    s = np.zeros((3, 3))
    for a in range(m):
        for b in range(m):
            acc = 0.0
            for i in range(N_ERR):
                if H[a, i] != 0.0:
                    for j in range(N_ERR):
                        acc += H[a, i] * P[i, j] * H[b, j]
            s[a, b] = acc
        s[a, a] += var[a]
    y = np.zeros(3)
    for a in range(m):
        y[a] = nu[a]
    # solve s z = y
    for c in range(m):
        piv = s[c, c]
        if not (piv > 0.0):
            return math.inf
        for r in range(c + 1, m):
            f = s[r, c] / piv
            for k in range(c, m):
                s[r, k] -= f * s[c, k]
            y[r] -= f * y[c]
    z = np.zeros(3)
    for c in range(m - 1, -1, -1):
        acc = y[c]
        for k in range(c + 1, m):
            acc -= s[c, k] * z[k]
        z[c] = acc / s[c, c]
    out = 0.0
    for a in range(m):
        out += nu[a] * z[a]
    return out


@njit(cache=True)
def _reset_block(P, e0, var):
    """Forget the correlations of the three error components e0.. and set their variances (a reset)."""
    for i in range(3):
        for j in range(N_ERR):
            P[e0 + i, j] = 0.0
            P[j, e0 + i] = 0.0
        P[e0 + i, e0 + i] = var[i]


@njit(cache=True)
def _correct_history(hist, x, t_from, dx, dpos_lat, dpos_lon, dpos_h):
    """Apply an attitude/velocity/position correction to the history rows after t_from (a later fix with a
    longer latency than the fix interval must not see the uncorrected past)."""
    n = int(x.hist_count)
    i = int(x.hist_newest)
    for _ in range(n):
        if hist[i].t_s <= t_from:
            break
        _rotate_attitude(hist[i].q, dx[0], dx[1], dx[2])
        for k in range(3):
            hist[i].vel_ned_m_s[k] += dx[E_V + k]
        hist[i].lat_rad += dpos_lat
        hist[i].lon_rad += dpos_lon
        hist[i].h_m += dpos_h
        i = (i - 1) % H_LEN


@njit(cache=True)
def _gated_update(gate, P, par, H, nu, var, m, dx, t_fix, may_reset, r_fused, r_rejected, r_reset, h_gate, nu_gate,
                  var_gate):
    """The χ² gate on m rows of one GNSS quantity (h_gate, nu_gate, var_gate), then its sequential scalar updates
    (H, nu, var: independent rows) into dx; on rejection, the start of the run of rejections is kept in `gate`
    (GNSS_GATE_DTYPE), and a run spanning reject_reset_s asks for a reset (r_reset) when `may_reset`. Returns the
    R_* bits."""
    nis = _nis(P, h_gate, nu_gate, var_gate, m)
    gate.nis = nis
    if nis <= par.gate_chi2[m - 1]:
        # while the heading is not known (ins.py decides), the horizontal GNSS acceleration projected through a
        # wrong yaw would be taken up by the horizontal accelerometer bias, which then holds a matching tilt error
        # that a steady turn cannot separate (pitch error, forward bias and gyro misalignment move together): the
        # x and y bias wait for a known heading; z (vertical on a near-level vehicle) learns on (docs/estimator.md
        # "A wrong heading must not teach the accelerometer bias"); nor the z axis's lean, which the vertical channel
        # learns against that tilt (the lean and a pitch are one error there); nor the x and y gyros' misalignment
        # towards z, which a turn with the yaw far off would set to keep that tilt in the body, where nothing on a
        # level turning vehicle undoes it ("The uncalibrated boat's tilt: the gyro misalignment learned before the
        # heading is known")
        zero = 0 if par.accel_bias_learn > 0.5 else M_ACC_BIAS_XY | M_ACC_Z_LEAN | M_GYRO_MIS_TURN
        for i in range(m):
            scalar_update(P, H[i], residual(H[i], nu[i], dx), var[i], zero, dx)
        gate.rejected_since_s = math.nan
        return r_fused
    if math.isnan(gate.rejected_since_s):
        gate.rejected_since_s = t_fix
    elif t_fix - gate.rejected_since_s >= par.reject_reset_s and may_reset:
        return r_rejected | r_reset
    return r_rejected


@njit(cache=True)
def _reset_from_fix(x, P, hist, par, t_fix, first, nu_v, nu_p, var_v, var_p, use_alt, use_vd, r_n, r_e, ph, plat):
    """The first fix, or the first after an outage longer than outage_reset_s: velocity and position set from
    it. Returns R_NAV_INIT or R_OUTAGE_RESET."""
    # velocity and position from the fix (antenna → IMU), attitude untouched; the shift is also applied
    # to the history so that the next fix compares with the reset trajectory. After an outage the
    # dead-reckoned velocity is metres per second off: fused, that error would be read as tilt all at
    # once (a step of tenths of a degree); reset, the tilt is corrected by the fixes that follow.
    dx = np.zeros(N_ERR)
    for i in range(3):
        dx[E_V + i] = nu_v[i]
        dx[E_P + i] = nu_p[i]
    if not use_vd:
        dx[E_V + 2] = -x.vel_ned_m_s[2]   # no vertical velocity: assume level motion
    if not use_alt:
        dx[E_P + 2] = 0.0           # 2D fix: keep the height
    for i in range(3):
        x.vel_ned_m_s[i] += dx[E_V + i]
    dlat = dx[E_P] / (r_n + ph)
    dlon = dx[E_P + 1] / ((r_e + ph) * math.cos(plat))
    x.lat_rad += dlat
    x.lon_rad += dlon
    x.h_m -= dx[E_P + 2]
    _reset_block(P, np.int64(E_V), var_v if use_vd else np.array([var_v[0], var_v[1], 1.0]))
    _reset_block(P, np.int64(E_P), var_p if use_alt else np.array([var_p[0], var_p[1], NAV_UNKNOWN_VAR_P]))
    # the tilt so far came from levelling, which leans by the unknown acceleration (a turn: a/g); its
    # small variance would make the GNSS read that lean as accelerometer bias: widen it
    st2 = par.nav_init_sigma_tilt_rad ** 2 if first or t_fix - x.gnss_fused_t_s > par.dead_reckon_s else 0.0
    for i in range(2):
        if P[i, i] < st2:
            for jj in range(N_ERR):
                P[i, jj] = 0.0
                P[jj, i] = 0.0
            P[i, i] = st2
    dx[0] = 0.0
    dx[1] = 0.0
    dx[2] = 0.0
    _correct_history(hist, x, t_fix - 1e-9, dx, dlat, dlon, -dx[E_P + 2])
    x.nav_ok = 1.0
    x.was_aided = 1.0
    x.gnss_fused_t_s = t_fix
    x.vel_gate.rejected_since_s = math.nan
    x.pos_gate.rejected_since_s = math.nan
    return R_NAV_INIT if first else R_OUTAGE_RESET


@njit(cache=True)
def _antenna_rows(par, c, on, oe, od, un, ue, ud):
    """The measurement rows H of the antenna's velocity (hv) and position (hp), 3 × N_ERR each: linearising
    v_ant = v + C (ω × r) and p_ant = p + C r (docs/estimator.md, "Lever arm") in the attitude error δθ, the
    velocity/position errors and the gyro bias δb_g (ω = gyro − b_g)."""
    lx = par.lever_arm_m[0]
    ly = par.lever_arm_m[1]
    lz = par.lever_arm_m[2]
    hv = np.zeros((3, N_ERR))
    hp = np.zeros((3, N_ERR))
    # v_ant rows: δv − [C(ω×r)×] δθ + C [r×] δb_g
    #   C [r×] = columns C·(e_k × ... ): (C [r×])[i, k] = Σ_m C[i, m] [r×][m, k]
    rs = ((0.0, -lz, ly), (lz, 0.0, -lx), (-ly, lx, 0.0))
    for i in range(3):
        hv[i, E_V + i] = 1.0
        _skew_rows(hv[i], i, un, ue, ud, 1.0)
        for kk in range(3):
            hv[i, E_BG + kk] = c[3 * i] * rs[0][kk] + c[3 * i + 1] * rs[1][kk] + c[3 * i + 2] * rs[2][kk]
        # p_ant rows: δp − [C r×] δθ
        hp[i, E_P + i] = 1.0
        _skew_rows(hp[i], i, on, oe, od, 1.0)
    return hv, hp


@njit(cache=True)
def _arm_consider(par, c, wx, wy, wz, dt_fix):
    """What the arm's uncertainty P_r (par.lever_arm_cov_m2, body) adds to the fix's noise: the arm is not estimated
    but fused as if exact, so its error is a consider parameter (Groves, Principles of GNSS, Inertial, and
    Multisensor Integrated Navigation Systems, 2nd ed., §14.2.1 the lever arm; the consider covariance of Schmidt's
    filter): the velocity's R gains U P_r Uᵀ with U = C [ω×] (v_ant = v + C (ω × r)), the position's C P_r Cᵀ
    (p_ant = p + C r), each times lever_arm_corr_s / dt_fix (≥ 1; dt_fix the time since the fix before): one error
    over that span, not a new one at every fix (time-correlated noise, Groves §3.4.3). Returns (3 × 3 velocity,
    3 × 3 position) in NED."""
    scale = 1.0
    if dt_fix > 0.0 and par.lever_arm_corr_s > dt_fix:
        scale = par.lever_arm_corr_s / dt_fix
    pr = scale * par.lever_arm_cov_m2
    cm = np.empty((3, 3))
    for i in range(3):
        for k in range(3):
            cm[i, k] = c[3 * i + k]
    # U = C [ω×]: column k of [ω×] is ω × e_k
    w = ((0.0, -wz, wy), (wz, 0.0, -wx), (-wy, wx, 0.0))
    u = np.zeros((3, 3))
    for i in range(3):
        for k in range(3):
            u[i, k] = cm[i, 0] * w[0][k] + cm[i, 1] * w[1][k] + cm[i, 2] * w[2][k]
    return _sandwich(u, pr), _sandwich(cm, pr)


@njit(cache=True)
def _sandwich(a, b):
    """a b aᵀ for 3 × 3 matrices."""
    ab = np.zeros((3, 3))
    for i in range(3):
        for k in range(3):
            ab[i, k] = a[i, 0] * b[0, k] + a[i, 1] * b[1, k] + a[i, 2] * b[2, k]
    out = np.zeros((3, 3))
    for i in range(3):
        for j in range(3):
            out[i, j] = ab[i, 0] * a[j, 0] + ab[i, 1] * a[j, 1] + ab[i, 2] * a[j, 2]
    return out


@njit(cache=True)
def _whitened(H, nu, var, add, m):
    """The m rows of H and nu with the noise diag(var) + add (correlated by the arm's part) made white: with
    L Lᵀ = R (Cholesky), L⁻¹ H, L⁻¹ ν and unit variances, which the sequential scalar updates and the χ² gate take
    as independent rows (the NIS is unchanged)."""
    r = np.zeros((3, 3))
    for a in range(m):
        for b in range(m):
            r[a, b] = add[a, b]
        r[a, a] += var[a]
    low = np.zeros((3, 3))
    for a in range(m):
        for b in range(a + 1):
            acc = r[a, b]
            for k in range(b):
                acc -= low[a, k] * low[b, k]
            low[a, b] = math.sqrt(acc) if a == b else acc / low[b, b]
    hw = np.zeros((3, N_ERR))
    nw = np.zeros(3)
    vw = np.ones(3)
    for a in range(m):
        nw[a] = nu[a]
        for j in range(N_ERR):
            hw[a, j] = H[a, j]
        for k in range(a):
            nw[a] -= low[a, k] * nw[k]
            for j in range(N_ERR):
                hw[a, j] -= low[a, k] * hw[k, j]
        nw[a] /= low[a, a]
        for j in range(N_ERR):
            hw[a, j] /= low[a, a]
    return hw, nw, vw


@njit(cache=True)
def _gate_velocity_and_position(x, P, par, hv, hp, nu_v, nu_p, var_v, var_p, dx, t_fix, use_pos, use_alt, use_vel,
                                use_vd, add_v, add_p):
    """The χ²-gated updates of the fix's velocity (m_v rows: 2 without a vertical velocity), then its position
    (2 rows on a 2D fix), into dx, their noise the receiver's plus what the arm's uncertainty makes of them
    (add_v, add_p: `_arm_consider`; none when the arm is exact). The gate judges each against the receiver's noise
    alone: a fix the arm's term puts beyond it is rejected as before, the evidence the lever-arm check reads
    (lever_arm_fit.py: an arm explains rejections), while what is fused is weighted with the arm's part. Returns
    the R_* bits of both."""
    res = 0
    hv_w, nu_v_w, var_v_w = hv, nu_v, var_v
    hp_w, nu_p_w, var_p_w = hp, nu_p, var_p
    if np.any(par.lever_arm_cov_m2 != 0.0):
        hv_w, nu_v_w, var_v_w = _whitened(hv, nu_v, var_v, add_v, 3 if use_vd else 2)
        hp_w, nu_p_w, var_p_w = _whitened(hp, nu_p, var_p, add_p, 3 if use_alt else 2)
    if use_vel:
        # a velocity reset needs the positions to disagree too (or none): a receiver whose velocity
        # contradicts its own positions is wrong, not the filter
        may_reset = not use_pos or not math.isnan(x.pos_gate.rejected_since_s)
        # the flags as np.int64 (np.bool_), not the constants: numba compiles a callee once per literal argument
        # it is passed, so velocity and position share one compile of _gated_update
        res |= _gated_update(x.vel_gate, P, par, hv_w, nu_v_w, var_v_w, 3 if use_vd else 2, dx, t_fix, may_reset,
                             np.int64(R_VEL_FUSED), np.int64(R_VEL_REJECTED), np.int64(R_VEL_RESET), hv, nu_v, var_v)
    if use_pos:
        res |= _gated_update(x.pos_gate, P, par, hp_w, nu_p_w, var_p_w, 3 if use_alt else 2, dx, t_fix,
                             np.bool_(True), np.int64(R_POS_FUSED), np.int64(R_POS_REJECTED), np.int64(R_POS_RESET),
                             hp, nu_p, var_p)
    return res


@njit(cache=True)
def _velocity_reset_to_fix(x, P, nu_v, var_v, m_v, dx):
    """After a persistent change the velocity jumps to the fix (attitude untouched): the part of the innovation
    the update did not take (nu_v − dx) is added, and dx holds the whole step for the history."""
    for i in range(m_v):
        x.vel_ned_m_s[i] += nu_v[i] - dx[E_V + i]
        dx[E_V + i] = nu_v[i]
    _reset_block(P, np.int64(E_V), var_v)
    x.vel_gate.rejected_since_s = math.nan


@njit(cache=True)
def _position_reset_to_fix(x, P, nu_p, var_p, dx, use_alt, r_n, r_e, ph, plat):
    """After a persistent change the position jumps to the fix (attitude untouched) by the part of the innovation
    the update did not take, δN, δE, δD metres → Δlat = δN / (R_N + h), Δlon = δE / ((R_E + h) cos lat),
    Δh = −δD (radii at the fix). Returns that extra (Δlat, Δlon, Δh) for the history."""
    extra_lat = (nu_p[0] - dx[E_P]) / (r_n + ph)
    extra_lon = (nu_p[1] - dx[E_P + 1]) / ((r_e + ph) * math.cos(plat))
    extra_h = -(nu_p[2] - dx[E_P + 2]) if use_alt else 0.0
    x.lat_rad += extra_lat
    x.lon_rad += extra_lon
    x.h_m += extra_h
    _reset_block(P, np.int64(E_P), var_p)
    x.pos_gate.rejected_since_s = math.nan
    return extra_lat, extra_lon, extra_h


@njit(cache=True)
def _fuse_fix(x, P, hist, par, t_fix, nu_v, nu_p, var_v, var_p, c, on, oe, od, un, ue, ud, pw, dt_fix, use_pos,
              use_alt, use_vel, use_vd, r_n, r_e, ph, plat):
    """The χ²-gated sequential updates of the fix's velocity and position (innovations nu_v, nu_p against the
    state at its time of validity; lever-arm terms C, C r, C (ω × r), ω = pw the body rate), folded into the
    state and the history (dt_fix: the time since the fix before, `_arm_consider`);
    a run of rejections lasting reject_reset_s resets that quantity to the fix. Returns R_* bits."""
    dx = np.zeros(N_ERR)
    hv, hp = _antenna_rows(par, c, on, oe, od, un, ue, ud)
    add_v, add_p = _arm_consider(par, c, pw[0], pw[1], pw[2], dt_fix)
    res = _gate_velocity_and_position(x, P, par, hv, hp, nu_v, nu_p, var_v, var_p, dx, t_fix, use_pos, use_alt,
                                      use_vel, use_vd, add_v, add_p)
    _symmetrise(P)
    lat_before = x.lat_rad
    lon_before = x.lon_rad
    h_before = x.h_m
    _apply_correction(x, par, dx)
    dlat = x.lat_rad - lat_before
    dlon = x.lon_rad - lon_before
    dh = x.h_m - h_before
    if res & R_VEL_RESET:
        _velocity_reset_to_fix(x, P, nu_v, var_v, 3 if use_vd else 2, dx)
    if res & R_POS_RESET:
        extra_lat, extra_lon, extra_h = _position_reset_to_fix(x, P, nu_p, var_p, dx, use_alt, r_n, r_e, ph, plat)
        dlat += extra_lat
        dlon += extra_lon
        dh += extra_h
    _correct_history(hist, x, t_fix, dx, dlat, dlon, dh)
    if res & (R_VEL_FUSED | R_POS_FUSED | R_VEL_RESET | R_POS_RESET):
        x.gnss_fused_t_s = t_fix
    return res


@njit(cache=True)
def _state_at_fix(hist, j, k, w):
    """The nominal state at a fix's time of validity, interpolated between the history rows j and k (w: the
    weight of k, `_history_at`): attitude (normalised), velocity, bias-corrected body rate, latitude, longitude
    and height."""
    a0 = hist[j].q[0] * (1.0 - w) + hist[k].q[0] * w
    a1 = hist[j].q[1] * (1.0 - w) + hist[k].q[1] * w
    a2 = hist[j].q[2] * (1.0 - w) + hist[k].q[2] * w
    a3 = hist[j].q[3] * (1.0 - w) + hist[k].q[3] * w
    a0, a1, a2, a3 = normalised(a0, a1, a2, a3)
    pv = np.zeros(3)
    pw = np.zeros(3)
    for i in range(3):
        pv[i] = hist[j].vel_ned_m_s[i] * (1.0 - w) + hist[k].vel_ned_m_s[i] * w
        pw[i] = hist[j].rate_rad_s[i] * (1.0 - w) + hist[k].rate_rad_s[i] * w
    plat = hist[j].lat_rad * (1.0 - w) + hist[k].lat_rad * w
    plon = hist[j].lon_rad * (1.0 - w) + hist[k].lon_rad * w
    ph = hist[j].h_m * (1.0 - w) + hist[k].h_m * w
    return a0, a1, a2, a3, pv, pw, plat, plon, ph


@njit(cache=True)
def _innovations(lat_fix, lon_fix, alt_fix, vn_fix, ve_fix, vd_fix, use_alt, use_vd, plat, plon, ph, pv, r_n, r_e,
                 on, oe, od, un, ue, ud):
    """(nu_p, nu_v): the fix's position and velocity less the state's at its time of validity (plat, plon, ph,
    pv) carried to the antenna (on, oe, od: C r; un, ue, ud: C (ω × r)), NED metres and m/s; the down component
    zero without a height (2D fix) or a vertical velocity."""
    nu_p = np.zeros(3)
    nu_p[0] = (lat_fix - plat) * (r_n + ph) - on
    nu_p[1] = (lon_fix - plon) * (r_e + ph) * math.cos(plat) - oe
    nu_p[2] = (-(alt_fix - ph) - od) if use_alt else 0.0
    nu_v = np.zeros(3)
    nu_v[0] = vn_fix - pv[0] - un
    nu_v[1] = ve_fix - pv[1] - ue
    nu_v[2] = (vd_fix - pv[2] - ud) if use_vd else 0.0
    return nu_p, nu_v


@njit(cache=True)
def fuse_gnss(state, P, hist, params, t_fix, lat_fix, lon_fix, alt_fix, vn_fix, ve_fix, vd_fix, sig_h, sig_v, sig_s,
              use_pos, use_alt, use_vel, use_vd):
    """Fuse one GNSS fix (angles in rad, σ in m and m/s) at its time of validity t_fix. Returns R_* bits.

    The innovation is formed against the nominal state interpolated from the history at t_fix (latency,
    `_state_at_fix`) and the antenna lever arm: p_ant = p + C r, v_ant = v + C (ω × r) (`_innovations`). The
    correction is applied to the current state with the current covariance (the error state changes little over
    the ≤ 1 s of latency). Velocity and position are gated separately by the χ² of their normalised innovation;
    a run of rejections lasting reject_reset_s resets that quantity to the fix (a real change, e.g. a receiver
    that switched to another solution) without touching the attitude (`_fuse_fix`). The first fix, and the
    first after an outage, set velocity and position (`_reset_from_fix`)."""
    x = state[0]
    par = params[0]
    if t_fix < x.t_last_s - par.max_delay_s:
        return R_TOO_OLD
    j, k, w = _history_at(x, hist, t_fix)
    if j < 0:
        return R_TOO_OLD
    propagate_covariance(x, P, par)
    dt_fix = t_fix - x.last_fix_t_s
    x.last_fix_t_s = t_fix
    a0, a1, a2, a3, pv, pw, plat, plon, ph = _state_at_fix(hist, j, k, w)
    on, oe, od, un, ue, ud, c = _lever_terms(a0, a1, a2, a3, pw[0], pw[1], pw[2],
                                             par.lever_arm_m[0], par.lever_arm_m[1], par.lever_arm_m[2])
    r_n, r_e = _radii(par, plat)
    nu_p, nu_v = _innovations(lat_fix, lon_fix, alt_fix, vn_fix, ve_fix, vd_fix, use_alt, use_vd, plat, plon, ph, pv,
                              r_n, r_e, on, oe, od, un, ue, ud)
    var_p = np.array([sig_h * sig_h, sig_h * sig_h, sig_v * sig_v])
    var_v = np.array([sig_s * sig_s, sig_s * sig_s, sig_s * sig_s])
    first = x.nav_ok <= 0.0
    outage = (not first) and t_fix - x.gnss_fused_t_s > par.outage_reset_s
    if first or outage:
        if not (use_pos and use_vel):
            return 0
        return _reset_from_fix(x, P, hist, par, t_fix, first, nu_v, nu_p, var_v, var_p, use_alt, use_vd, r_n, r_e,
                               ph, plat)
    return _fuse_fix(x, P, hist, par, t_fix, nu_v, nu_p, var_v, var_p, c, on, oe, od, un, ue, ud, pw, dt_fix,
                     use_pos, use_alt, use_vel, use_vd, r_n, r_e, ph, plat)


def fast_step(example_args):
    """`ins_step` compiled for the types of `example_args` and returned as that overload's directly callable
    entry point (kernel_entry.py)."""
    return entry_point(ins_step, argument_types(ins_step, example_args))
