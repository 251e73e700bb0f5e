"""The `ins` estimator's compiled kernels (numba): NED strapdown mechanisation, 24-state error covariance,
accelerometer levelling while unaided, magnetometer heading, and the delayed GNSS velocity/position fusion.

`ins.py` owns the parameters, initialisation, input checks and the Estimator interface; this module is the
arithmetic. Arrays: `x` (nominal state and bookkeeping, layout `X_*`), `P` (24×24 error covariance), `hist`
(ring buffer of past nominal states for fusing a fix at its time of validity, layout `H_*`), `par`
(parameters, layout `P_*`), `out` (per-step outputs, layout `O_*`).

Nominal state: attitude q (body FRD → true-north NED, Hamilton scalar first), NED velocity v, WGS-84 geodetic
position (L, λ, h), gyro bias b_g, accelerometer bias b_a (body frame), gyro scale factors and misalignment.
Error state δx (24, true − estimate), in this order:
  δθ (0–2)  attitude error in NED, C_true = (I + [δθ×]) C_est; tilt δθ_N, δθ_E, heading δθ_D
  δv (3–5)  velocity error, NED, m/s
  δp (6–8)  position error, NED, m
  δb_g (9–11) gyro bias error, rad/s;  δb_a (12–14) accelerometer bias error, m/s²
  δs_g (15–17) gyro scale-factor error (ω_meas = (I + diag(s) + M) ω + b), fraction
  δm_g (18–23) gyro misalignment M's off-diagonal elements xy, xz, yx, yz, zx, zy (ω_j picks up m_jk ω_k), rad
Error dynamics (Groves 2nd ed. ch. 14; the ω_in^n × δθ, Coriolis and gravity-gradient couplings are
below the ADIS16405's noise over the filter's time constants and are left out):
  δθ̇ = −C δb_g − C diag(ω) δs_g − C W(ω) δm_g + w_g,  δv̇ = −[f^n×] δθ − C δb_a + w_a,  δṗ = δv,  biases,
  scale factors and misalignments random walks (W(ω): the 3×6 map of δm_g into δω). An uncalibrated 0.3 %
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
from .gsf_yaw import gsf_accumulate_imu
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
from .kernel_rotations import dcm, euler_and_tilt_sigma, normalised, quat_mul, rotate_to_ned, rotvec_quat

N_ERR = 24
E_TH, E_V, E_P, E_BG, E_BA, E_SG, E_MG = 0, 3, 6, 9, 12, 15, 18
# (row j, column k) of each misalignment error component E_MG + n: δω_j = δm_jk ω_k
MIS_ROW = (0, 0, 1, 1, 2, 2)
MIS_COL = (1, 2, 0, 2, 0, 1)

# ----------------------------------------------------------------------------------- nominal state x
X_Q = 0            # 4 attitude body → true NED
X_V = 4            # 3 velocity NED, m/s
X_LAT = 7          # rad
X_LON = 8          # rad
X_H = 9            # height above the ellipsoid, m
X_BG = 10          # 3 gyro bias, rad/s
X_BA = 13          # 3 accelerometer bias, m/s² (body)
X_T_LAST = 16      # time of the previous sample, s
X_T_RUN = 17       # time since initialisation, s
X_COV_T = 18       # time accumulated since the last covariance propagation, s
X_COV_C = 19       # 9: ∫ C_b^n dt over that time (row-major), s
X_COV_DV = 28      # 3: ∫ f^n dt over that time, m/s
X_ACC_LP = 31      # 3: specific force low-passed in the estimated NED frame (levelling), m/s²
X_ACC_HOLD_T = 34  # levelling stays off this much longer after a sustained push, s
X_ACC_REJ_T = 35   # time since the last accepted levelling update, s
X_GYR_LAST = 36    # 3: last valid gyro, rad/s
X_ACC_LAST = 39    # 3: last valid accelerometer, m/s²
X_MAG_LAST = 42    # 3: last valid magnetometer, µT (NaN: none yet)
X_NAV_OK = 45      # 1.0 once velocity/position have been set from a fix
X_GNSS_LAST_T = 46  # time of validity of the last fused fix, s (−inf: none)
X_VEL_REJ_T0 = 47  # time of validity of the first of the current run of rejected velocities (NaN: none)
X_POS_REJ_T0 = 48  # ... positions
X_HIST_I = 49      # index of the newest history row
X_HIST_N = 50      # rows of history filled
X_WAS_AIDED = 51   # 1.0 once a fix has been fused (GNSS_OUTAGE only after that)
X_LAST_FIX_T = 52  # time of validity of the last fix offered (accepted or not), s
X_NIS_V = 53       # normalised innovation squared of the last velocity fusion (diagnostic)
X_NIS_P = 54       # ... position
X_SG = 56          # 3 gyro scale-factor errors (ω_meas = (I + diag(s) + M) ω + b), fraction
X_MG = 59          # 6 gyro misalignment M: xy, xz, yx, yz, zx, zy (MIS_ROW, MIS_COL), rad
X_COV_CWW = 68     # 27: ∫ C_ij ω_k dt since the last covariance propagation (index 9 i + 3 j + k), rad
X_MAG = 95         # the magnetometer heading check's state: a mag_heading.MAG_HEADING_STATE_DTYPE record
MAG_STATE_SIZE = mag.MAG_HEADING_STATE_DTYPE.itemsize // 8
X_SIZE = X_MAG + MAG_STATE_SIZE

# ----------------------------------------------------------------------------------- history ring buffer
H_LEN = 1024       # rows: 1.25 s at 819.2 SPS (fixes older than the oldest row are not fused)
H_T = 0
H_Q = 1            # 4
H_V = 5            # 3
H_LAT = 8
H_LON = 9
H_H = 10
H_W = 11           # 3 bias-corrected body rate (lever arm), rad/s
H_SIZE = 14

# ----------------------------------------------------------------------------------- parameters
P_GYRO_NOISE = 0        # gyro angle random walk, rad/s/√Hz
P_GYRO_BIAS_WALK = 1    # gyro bias random walk, rad/s/√s
P_ACC_NOISE_DENS = 2    # accelerometer velocity random walk, m/s²/√Hz
P_ACC_BIAS_WALK = 3     # accelerometer bias random walk, m/s²/√s
P_GYRO_BIAS_CLIP = 4    # |b_g| limit per axis, rad/s
P_ACC_BIAS_CLIP = 5     # |b_a| limit per axis, m/s²
P_COV_PERIOD = 6        # covariance propagation period, s
P_EARTH_ROT = 7         # 1.0: rotating Earth (Earth rate, transport rate, Coriolis)
P_LEVEL_NOISE = 8       # levelling: noise of the low-passed specific force as a gravity measurement, m/s²
P_LEVEL_REJECT = 9      # levelling off while | |f_lp| − g | exceeds this, m/s²
P_LEVEL_GATE = 10       # levelling tilt gate, rad
P_LEVEL_TAU = 11        # low-pass time constant, s
P_LEVEL_RECOVER = 12    # after this long without a levelling update, the rejection is overridden, s
P_MAG_ENABLED = 13      # 1.0: magnetometer heading updates
P_DECLINATION = 14      # magnetic declination, rad (true = magnetic + declination)
P_LEVER = 15            # 3: antenna position in the body frame relative to the IMU, m
P_GATE_CHI2 = 18        # 3: innovation gate (χ² threshold) for 1, 2, 3 degrees of freedom
P_REJECT_RESET = 21     # a run of rejections this long resets that quantity to the fix, s
P_DEAD_RECKON = 22      # without a fused fix for this long, levelling resumes (unaided), s
P_OUTAGE_RESET = 23     # the first fix after an outage longer than this resets velocity and position, s
P_MAX_DELAY = 24        # fixes older than this (behind the newest sample) are not fused, s
P_LARGE_DT = 25         # Δt above this (or ≤ 0) is flagged LARGE_DT, s
P_REINIT_DT = 26        # Δt above this re-initialises, s
P_INIT_TIME = 27        # INITIALISING held at least this long, s
P_CONV_TILT = 28        # ... and until 1σ tilt is below this, rad
P_CONV_YAW = 29         # ... and 1σ heading is below this, rad
P_GNSS_TIMEOUT = 30     # no fused fix for this long: GNSS_OUTAGE, s
P_NAV_INIT_TILT = 31    # 1σ tilt assumed when a fix first sets velocity/position (levelled tilt leans), rad
P_NAV_DROP = 44         # without a fused fix for this long, velocity and position are dropped, s
P_SPHERE = 45           # 1.0: spherical Earth (radius R0 = 6 378 137 m) instead of the WGS-84 ellipsoid's radii
P_MAG = 32              # 32–43: the magnetometer check's parameters, a mag_heading.MAG_HEADING_PARAMS_DTYPE record
P_GYRO_SCALE_WALK = 46  # gyro scale-factor random walk, 1/√s
P_GYRO_SCALE_CLIP = 47  # |s| and |m| limit per element
P_GYRO_MIS_WALK = 48    # gyro misalignment random walk, rad/√s
P_MAG_TILT = 49         # 1.0: while aided the magnetometer update may move the tilt (0: its tilt gain is zero)
P_MAG_USE = 50          # 1.0: fuse the magnetometer heading; 0.0: the heading monitor rejects it (heading_monitor.py)
P_MAG_BIAS_VAR = 51     # variance of the slowly varying part of the magnetometer heading error (calibration), rad²
P_MAG_BIAS_TAU = 52     # its correlation time, s: each update's noise is inflated by τ/Δt (see _mag_update)
P_IRON = 53             # 3: learned hard iron (body frame) removed from the magnetometer before use, µT
P_GSF = 56              # 1.0: run the Gaussian-sum GNSS yaw bank beside the filter
P_SIZE = 57
MAG_PAR_SIZE = mag.MAG_HEADING_PARAMS_DTYPE.itemsize // 8
assert P_MAG + MAG_PAR_SIZE <= P_NAV_DROP < P_SIZE

# ----------------------------------------------------------------------------------- outputs
O_Q = 0        # 4 body → magnetic NED (the AttitudeEstimate convention)
O_RATE = 4     # 3
O_SIGMA = 7    # 3 roll, pitch, yaw 1σ
O_BG = 10      # 3
O_EULER = 13   # 3 roll, pitch, yaw (true)
O_VEL = 16     # 3
O_POS = 19     # 3 lat rad, lon rad, h m
O_SIG_V = 22   # 3
O_SIG_P = 25   # 3
O_BA = 28      # 3
O_SIZE = 31

# ----------------------------------------------------------------------------------- GNSS fusion results (bits)
R_VEL_FUSED = 1
R_POS_FUSED = 2
R_VEL_REJECTED = 4
R_POS_REJECTED = 8
R_VEL_RESET = 16       # a persistent change: velocity reset to the fix after a run of rejections
R_POS_RESET = 32
R_NAV_INIT = 64        # first fix: velocity and position set from it
R_TOO_OLD = 128        # older than the history (or than P_MAX_DELAY): not fused
R_OUTAGE_RESET = 256   # first fix after an outage: velocity and position set from it, attitude untouched

# error-state component masks (bit i = error-state component i) for `scalar_update`
M_TILT = 0b11
M_HEADING = 0b100
M_GYRO_BIAS = 0b111 << E_BG
M_ACC_BIAS = 0b111 << E_BA
M_GYRO_SCALE = 0b111 << E_SG
M_GYRO_MIS = 0b111111 << E_MG
M_NAV = 0b111111 << E_V
NAV_UNKNOWN_VAR_V = 100.0    # (10 m/s)², velocity variance before a fix sets it
NAV_UNKNOWN_VAR_P = 1e6      # (1 km)², position variance before a fix sets it


# ----------------------------------------------------------------------------------- small helpers
@njit(cache=True)
def _radii(par, lat):
    """(R_N, R_E) of the configured Earth model, m."""
    if par[P_SPHERE] > 0.0:
        return SPHERE_RADIUS_M, SPHERE_RADIUS_M
    return radii_of_curvature_m(lat)


@njit(cache=True)
def _rotate_attitude(x, i0, dth0, dth1, dth2):
    """q ← exp(δθ) ⊗ q (NED-frame attitude correction) for the quaternion stored at x[i0:i0+4]."""
    h0, h1, h2, h3 = rotvec_quat(dth0, dth1, dth2)
    n0, n1, n2, n3 = quat_mul(h0, h1, h2, h3, x[i0], x[i0 + 1], x[i0 + 2], x[i0 + 3])
    x[i0], x[i0 + 1], x[i0 + 2], x[i0 + 3] = normalised(n0, n1, n2, n3)


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
    _rotate_attitude(x, X_Q, dx[0], dx[1], dx[2])
    for i in range(3):
        x[X_V + i] += dx[E_V + i]
    lat = x[X_LAT]
    r_n, r_e = _radii(par, lat)
    x[X_LAT] = lat + dx[E_P] / (r_n + x[X_H])
    x[X_LON] += dx[E_P + 1] / ((r_e + x[X_H]) * math.cos(lat))
    x[X_H] -= dx[E_P + 2]
    gc = par[P_GYRO_BIAS_CLIP]
    ac = par[P_ACC_BIAS_CLIP]
    sc = par[P_GYRO_SCALE_CLIP]
    for i in range(3):
        x[X_BG + i] = min(max(x[X_BG + i] + dx[E_BG + i], -gc), gc)
        x[X_BA + i] = min(max(x[X_BA + i] + dx[E_BA + i], -ac), ac)
        x[X_SG + i] = min(max(x[X_SG + i] + dx[E_SG + i], -sc), sc)
    for i in range(6):
        x[X_MG + i] = min(max(x[X_MG + i] + dx[E_MG + i], -sc), sc)
    # the NED-frame low-passed specific force lives in the estimated NED frame: keep it there
    an = x[X_ACC_LP]
    ae = x[X_ACC_LP + 1]
    ad = x[X_ACC_LP + 2]
    x[X_ACC_LP] = an + dx[1] * ad - dx[2] * ae
    x[X_ACC_LP + 1] = ae + dx[2] * an - dx[0] * ad
    x[X_ACC_LP + 2] = ad + dx[0] * ae - dx[1] * an


@njit(cache=True)
def _gyro_matrix_corrected(x, ux, uy, uz):
    """(I − diag(s) − M) u: the bias-corrected rate u with the scale-factor and misalignment estimates removed
    (first order of (I + diag(s) + M)⁻¹, exact to < 1e-5 relative for |s|, |m| < 0.3 %)."""
    return (ux - x[X_SG] * ux - x[X_MG] * uy - x[X_MG + 1] * uz,
            uy - x[X_SG + 1] * uy - x[X_MG + 2] * ux - x[X_MG + 3] * uz,
            uz - x[X_SG + 2] * uz - x[X_MG + 4] * ux - x[X_MG + 5] * uy)


@njit(cache=True)
def _accumulate_c_omega(x, c00, c01, c02, c10, c11, c12, c20, c21, c22, tx, ty, tz):
    """∫ C_ij ω_k dt += C_ij θ_k for the step's rotation increment θ = ω dt (Φ's scale/misalignment blocks)."""
    c = (c00, c01, c02, c10, c11, c12, c20, c21, c22)
    for ij in range(9):
        b = X_COV_CWW + 3 * ij
        x[b] += c[ij] * tx
        x[b + 1] += c[ij] * ty
        x[b + 2] += c[ij] * tz


# ----------------------------------------------------------------------------------- covariance propagation
@njit(cache=True)
def transition_matrix(x, par):
    """Φ (N_ERR × N_ERR) of the interval accumulated since the last propagation (X_COV_T, the sums ∫C dt,
    ∫C ω dt, ΔV^n), as `propagate_covariance` applies it (3×3 blocks, order δθ, δv, δp, δb_g, δb_a, then δs_g,
    δm_g), with A = −∫C dt and B = −[ΔV^n×]:
        δθ: [I, 0, 0, A, 0, −∫C diag(ω) dt, −∫C W(ω) dt];  δv: [B, I, 0, 0, A, 0, 0];
        δp: [½T B, T I, I, 0, ½T A, 0, 0];  biases, scale factors, misalignments: identity.
    The offline smoother (ins_smoother.py) reads it too."""
    T = x[X_COV_T]
    phi = np.eye(N_ERR)
    for i in range(3):
        for j in range(3):
            phi[E_TH + i, E_SG + j] = -x[X_COV_CWW + 9 * i + 4 * j]   # δθ̇ = −C diag(ω) δs: ∫ C_ij ω_j
            a = -x[X_COV_C + 3 * i + j]
            phi[E_TH + i, E_BG + j] = a
            phi[E_V + i, E_BA + j] = a
            phi[E_P + i, E_BA + j] = 0.5 * T * a
        for n in range(6):   # δθ̇ = −C W(ω) δm: δm_jk moves ω_j by δm_jk ω_k
            phi[E_TH + i, E_MG + n] = -x[X_COV_CWW + 9 * i + 3 * MIS_ROW[n] + MIS_COL[n]]
    dvn = x[X_COV_DV]
    dve = x[X_COV_DV + 1]
    dvd = x[X_COV_DV + 2]
    # B = −[ΔV×]
    b = ((0.0, dvd, -dve), (-dvd, 0.0, dvn), (dve, -dvn, 0.0))
    for i in range(3):
        phi[E_P + i, E_V + i] = T
        for j in range(3):
            phi[E_V + i, E_TH + j] = b[i][j]
            phi[E_P + i, E_TH + j] = 0.5 * T * b[i][j]
    return phi


@njit(cache=True)
def propagate_covariance(x, P, par):
    """P ← Φ P Φᵀ + Q over the time accumulated since the last call (X_COV_T), then clear the sums.

    Φ: `transition_matrix`. Q: white gyro and accelerometer noise and bias random walks, density² · T on the
    diagonal (isotropic, so rotating it by C changes nothing)."""
    T = x[X_COV_T]
    if T <= 0.0:
        return
    phi = transition_matrix(x, par)
    # M = Φ P (skipping Φ's zeros), then P = M Φᵀ
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
    qg = par[P_GYRO_NOISE] ** 2 * T
    qa = par[P_ACC_NOISE_DENS] ** 2 * T
    qbg = par[P_GYRO_BIAS_WALK] ** 2 * T
    qba = par[P_ACC_BIAS_WALK] ** 2 * T
    for i in range(3):
        P[E_TH + i, E_TH + i] += qg
        P[E_V + i, E_V + i] += qa
        P[E_P + i, E_P + i] += qa * T * T / 3.0
        P[E_P + i, E_V + i] += 0.5 * qa * T
        P[E_V + i, E_P + i] += 0.5 * qa * T
        P[E_BG + i, E_BG + i] += qbg
        P[E_BA + i, E_BA + i] += qba
        P[E_SG + i, E_SG + i] += par[P_GYRO_SCALE_WALK] ** 2 * T
        P[E_MG + i, E_MG + i] += par[P_GYRO_MIS_WALK] ** 2 * T
        P[E_MG + 3 + i, E_MG + 3 + i] += par[P_GYRO_MIS_WALK] ** 2 * T
    _symmetrise(P)
    x[X_COV_T] = 0.0
    for i in range(9):
        x[X_COV_C + i] = 0.0
    for i in range(27):
        x[X_COV_CWW + i] = 0.0
    for i in range(3):
        x[X_COV_DV + i] = 0.0


# ----------------------------------------------------------------------------------- the per-sample step
@njit(cache=True)
def _aided(x, par):
    """Velocity/position known and a fix fused less than P_DEAD_RECKON ago: the accelerometer is left to the
    mechanisation (no levelling)."""
    return x[X_NAV_OK] > 0.0 and x[X_T_LAST] - x[X_GNSS_LAST_T] < par[P_DEAD_RECKON]


@njit(cache=True)
def _level(x, P, par, dt_epoch):
    """Accelerometer levelling (tilt only) from the NED-frame low-passed specific force, with mekf's gating:
    off while | |f_lp| − g | > P_LEVEL_REJECT or the low-passed vertical is more than P_LEVEL_GATE from the
    estimate, then held off for 4 τ (until the low-pass has forgotten the push), unless nothing was accepted
    for P_LEVEL_RECOVER. Tilt only: heading, gyro and accelerometer biases get no gain — the levelled vertical
    leans into any sustained acceleration (a boat's turn, a/g), an error that is not white noise, and learnt
    into the biases it would survive the return of GNSS (which then reads the lean as a bias). Returns
    F_ACCEL_REJECTED or 0."""
    un = x[X_ACC_LP]
    ue = x[X_ACC_LP + 1]
    ud = x[X_ACC_LP + 2]
    unorm = math.sqrt(un * un + ue * ue + ud * ud)
    g = normal_gravity_m_s2(x[X_LAT], x[X_H]) if x[X_NAV_OK] > 0.0 else 9.80665
    if unorm <= 0.5 * g:
        x[X_ACC_REJ_T] += dt_epoch
        return F_ACCEL_REJECTED
    nu_n = un / unorm     # = δθ_E (+ noise): the measured "up" is [δθ_E, −δθ_N, −1]
    nu_e = ue / unorm     # = −δθ_N
    tau = par[P_LEVEL_TAU]
    if abs(unorm - g) > par[P_LEVEL_REJECT] or nu_n * nu_n + nu_e * nu_e > par[P_LEVEL_GATE] ** 2:
        x[X_ACC_HOLD_T] = 4.0 * tau
    elif x[X_ACC_HOLD_T] > 0.0:
        x[X_ACC_HOLD_T] -= dt_epoch
    if x[X_ACC_HOLD_T] > 0.0 and x[X_ACC_REJ_T] <= par[P_LEVEL_RECOVER]:
        x[X_ACC_REJ_T] += dt_epoch
        return F_ACCEL_REJECTED
    r = (par[P_LEVEL_NOISE] / g) ** 2
    mask = M_HEADING | M_ACC_BIAS | M_GYRO_BIAS | M_GYRO_SCALE | M_GYRO_MIS   # tilt only (see the docstring)
    dx = np.zeros(N_ERR)
    h = np.zeros(N_ERR)
    h[1] = 1.0
    scalar_update(P, h, nu_n, r, mask, dx)
    h[1] = 0.0
    h[0] = -1.0
    scalar_update(P, h, residual(h, nu_e, dx), r, mask, dx)
    _apply_correction(x, par, dx)
    x[X_ACC_REJ_T] = 0.0
    return 0


@njit(cache=True)
def _mag_update(x, P, par, dt_epoch, rate):
    """Magnetometer heading update (the shared check of mag_heading.py): returns flag bits."""
    ms = x[X_MAG : X_MAG + MAG_STATE_SIZE].view(mag.MAG_HEADING_STATE_DTYPE)[0]
    mp = par[P_MAG : P_MAG + MAG_PAR_SIZE].view(mag.MAG_HEADING_PARAMS_DTYPE)[0]
    flags = 0
    used = False
    mx = x[X_MAG_LAST]
    my = x[X_MAG_LAST + 1]
    mz = x[X_MAG_LAST + 2]
    if par[P_MAG_ENABLED] > 0.0 and par[P_MAG_USE] > 0.0 and math.isfinite(mx):
        mx -= par[P_IRON]
        my -= par[P_IRON + 1]
        mz -= par[P_IRON + 2]
        mn, me, md = rotate_to_ned(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3], mx, my, mz)
        mnorm = math.sqrt(mx * mx + my * my + mz * mz)
        # the heading of the horizontal field depends on the tilt too: with m = H u + Z e_D (u the magnetic
        # north), m_est = m − δθ × m gives α = −δθ_D + (Z/H) u·δθ, so a tilt error along magnetic north reads
        # as tan(dip) times as much heading error (3.4× at 60° N). While fixes hold the horizon (GNSS_AIDED)
        # the row carries that sensitivity, so the heading correction allows for the known tilt error through
        # their covariance; the gain on the tilt itself is zero (a wrong magnetometer must never move the
        # horizon) unless mag_moves_tilt. Otherwise — before the first fix, dead reckoning, levelling — the row
        # is heading only, as in mekf.
        h = np.zeros(N_ERR)
        h[2] = -1.0
        aided = x[X_NAV_OK] > 0.0 and x[X_T_LAST] - x[X_GNSS_LAST_T] <= par[P_GNSS_TIMEOUT]
        moves_tilt = aided and par[P_MAG_TILT] > 0.0
        mh2 = mn * mn + me * me
        if aided and mh2 > 0.0:
            h[0] = md * mn / mh2
            h[1] = md * me / mh2
        hph = 0.0
        for i in range(3):
            for j in range(3):
                hph += h[i] * P[i, j] * h[j]
        res, alpha, r = mag.heading_measurement(ms, mp, dt_epoch, rate, False, False, mn, me, md,
                                                mnorm, par[P_DECLINATION], hph + par[P_MAG_BIAS_VAR])
        if res == mag.MAG_USE:
            # the calibration's error is not white: a heading bias of variance P_MAG_BIAS_VAR that lasts about
            # P_MAG_BIAS_TAU. Fused every Δt as if white it would shrink the heading σ below it; spread over the
            # τ/Δt updates of one correlation time it adds at most its own variance's worth of information.
            r += par[P_MAG_BIAS_VAR] * max(1.0, par[P_MAG_BIAS_TAU] / max(dt_epoch, 1e-6))
            dx = np.zeros(N_ERR)
            scalar_update(P, h, alpha, r, 0 if moves_tilt else M_TILT, dx)
            _apply_correction(x, par, dx)
            used = True
        elif res == mag.MAG_REJECTED:
            flags |= F_MAG_REJECTED
    elif par[P_MAG_ENABLED] > 0.0 and math.isfinite(mx):
        flags |= F_MAG_REJECTED     # the heading monitor rejects it (disagrees with GNSS or its own innovations)
    if mag.heading_bookkeeping(ms, mp, dt_epoch, used):
        flags |= F_MAG_UNAVAILABLE
    return flags


@njit(cache=True)
def ins_step(x, P, hist, par, t_s, gx, gy, gz, ax, ay, az, mx, my, mz, sample_flags, out, gsf, gsf_par):
    """One IMU sample: mechanise, accumulate the covariance increments, every P_COV_PERIOD propagate the
    covariance and run the levelling (when unaided) and magnetometer updates; feed the magnetometer-free GNSS
    yaw bank (`gsf`, `gsf_par`: 1-element record arrays of gsf_yaw.py's state and parameters — arrays unbox
    far cheaper per call than records; its own tilt and yaw, never this filter's heading) the bias-corrected sample;
    fill `out`. Returns
    EstimateFlags bits (| NEEDS_INIT when the caller must initialise from this sample first)."""
    valid = input_validity(sample_flags, gx, gy, gz, ax, ay, az, mx, my, mz)
    dt, flags = step_dt(t_s - x[X_T_LAST], par[P_LARGE_DT], par[P_REINIT_DT])
    if flags & NEEDS_INIT:
        return flags
    if dt > 0.0:
        x[X_T_LAST] = t_s
    x[X_T_RUN] += dt
    # the samples are instantaneous values at their times: over the step use the mean of the previous and
    # this one (trapezoid; the last sample alone lags by half a step: ½ Δt · Δω of heading per change of rate)
    pgx = x[X_GYR_LAST]
    pgy = x[X_GYR_LAST + 1]
    pgz = x[X_GYR_LAST + 2]
    pax = x[X_ACC_LAST]
    pay = x[X_ACC_LAST + 1]
    paz = x[X_ACC_LAST + 2]
    if valid & IN_GYRO_OK:
        x[X_GYR_LAST] = gx
        x[X_GYR_LAST + 1] = gy
        x[X_GYR_LAST + 2] = gz
    if valid & IN_ACC_OK:
        x[X_ACC_LAST] = ax
        x[X_ACC_LAST + 1] = ay
        x[X_ACC_LAST + 2] = az
    if valid & IN_MAG_OK:
        x[X_MAG_LAST] = mx
        x[X_MAG_LAST + 1] = my
        x[X_MAG_LAST + 2] = mz
    wx = x[X_GYR_LAST] - x[X_BG]
    wy = x[X_GYR_LAST + 1] - x[X_BG + 1]
    wz = x[X_GYR_LAST + 2] - x[X_BG + 2]
    mwx = 0.5 * (pgx + x[X_GYR_LAST]) - x[X_BG]
    mwy = 0.5 * (pgy + x[X_GYR_LAST + 1]) - x[X_BG + 1]
    mwz = 0.5 * (pgz + x[X_GYR_LAST + 2]) - x[X_BG + 2]
    # scale factor and misalignment: ω = (I + diag(s) + M)⁻¹ (ω_meas − b) ≈ (I − diag(s) − M)(ω_meas − b)
    wx, wy, wz = _gyro_matrix_corrected(x, wx, wy, wz)
    mwx, mwy, mwz = _gyro_matrix_corrected(x, mwx, mwy, mwz)
    fx = 0.5 * (pax + x[X_ACC_LAST]) - x[X_BA]
    fy = 0.5 * (pay + x[X_ACC_LAST + 1]) - x[X_BA + 1]
    fz = 0.5 * (paz + x[X_ACC_LAST + 2]) - x[X_BA + 2]
    if par[P_GSF] > 0.0:
        gsf_accumulate_imu(gsf[0], gsf_par[0], dt, np.array((mwx, mwy, mwz)), np.array((fx, fy, fz)))
    q0 = x[X_Q]
    q1 = x[X_Q + 1]
    q2 = x[X_Q + 2]
    q3 = x[X_Q + 3]
    c00, c01, c02, c10, c11, c12, c20, c21, c22 = dcm(q0, q1, q2, q3)
    lat = x[X_LAT]
    h_m = x[X_H]
    vn = x[X_V]
    ve = x[X_V + 1]
    vd = x[X_V + 2]
    r_n, r_e = _radii(par, lat)
    nav_ok = x[X_NAV_OK] > 0.0
    if nav_ok and x[X_T_LAST] - x[X_GNSS_LAST_T] > par[P_NAV_DROP]:
        # so long without a fix that velocity and position mean nothing: stop integrating them (the next fix
        # sets them again, as the first one did)
        nav_ok = False
        x[X_NAV_OK] = 0.0
        for i in range(3):
            x[X_V + i] = 0.0
        vn = ve = vd = 0.0
    earth = par[P_EARTH_ROT] > 0.0 and nav_ok   # the Earth rate needs the latitude
    if dt > 0.0:
        # body rate relative to NED: ω_nb = ω_ib − C_n^b (ω_ie + ω_en)   (as in Groves 2nd ed. eq. 5.77)
        rx, ry, rz = mwx, mwy, mwz
        if earth:
            en, ee, ed = earth_rate_ned(lat)
            tn, te, td = transport_rate_ned(lat, h_m, vn, ve, r_n, r_e)
            sn = en + tn
            se = ee + te
            sd = ed + td
            rx -= c00 * sn + c10 * se + c20 * sd
            ry -= c01 * sn + c11 * se + c21 * sd
            rz -= c02 * sn + c12 * se + c22 * sd
        thx = rx * dt
        thy = ry * dt
        thz = rz * dt
        # specific force at the middle of the step: f + ½ θ × f in the body frame at the start
        mfx = fx + 0.5 * (thy * fz - thz * fy)
        mfy = fy + 0.5 * (thz * fx - thx * fz)
        mfz = fz + 0.5 * (thx * fy - thy * fx)
        fn = c00 * mfx + c01 * mfy + c02 * mfz
        fe = c10 * mfx + c11 * mfy + c12 * mfz
        fd = c20 * mfx + c21 * mfy + c22 * mfz
        # attitude: C_b^n ← C_b^n exp(ω_nb dt)   (eq. 20)
        e0, e1, e2, e3 = rotvec_quat(thx, thy, thz)
        n0, n1, n2, n3 = quat_mul(q0, q1, q2, q3, e0, e1, e2, e3)
        q0, q1, q2, q3 = normalised(n0, n1, n2, n3)
        x[X_Q] = q0
        x[X_Q + 1] = q1
        x[X_Q + 2] = q2
        x[X_Q + 3] = q3
        # velocity (eq. 14) and position (eq. 17, trapezoid); before the first fix they are unknown and held
        nvn, nve, nvd = vn, ve, vd
        if nav_ok:
            an, ae, ad = velocity_rate_ned(fn, fe, fd, vn, ve, vd, lat, h_m, r_n, r_e, earth)
            nvn = vn + an * dt
            nve = ve + ae * dt
            nvd = vd + ad * dt
            ldot, odot, hdot = position_rates(lat, h_m, 0.5 * (vn + nvn), 0.5 * (ve + nve), 0.5 * (vd + nvd),
                                              r_n, r_e)
            x[X_V] = nvn
            x[X_V + 1] = nve
            x[X_V + 2] = nvd
            x[X_LAT] = lat + ldot * dt
            x[X_LON] += odot * dt
            x[X_H] = h_m + hdot * dt
        # covariance increments
        x[X_COV_T] += dt
        x[X_COV_C] += c00 * dt
        x[X_COV_C + 1] += c01 * dt
        x[X_COV_C + 2] += c02 * dt
        x[X_COV_C + 3] += c10 * dt
        x[X_COV_C + 4] += c11 * dt
        x[X_COV_C + 5] += c12 * dt
        x[X_COV_C + 6] += c20 * dt
        x[X_COV_C + 7] += c21 * dt
        x[X_COV_C + 8] += c22 * dt
        x[X_COV_DV] += fn * dt
        x[X_COV_DV + 1] += fe * dt
        x[X_COV_DV + 2] += fd * dt
        _accumulate_c_omega(x, c00, c01, c02, c10, c11, c12, c20, c21, c22, mwx * dt, mwy * dt, mwz * dt)
        # NED-frame low-pass of the specific force for the levelling (linear acceleration averages out)
        tau = par[P_LEVEL_TAU]
        k = 1.0 - math.exp(-dt / tau) if tau > 0.0 else 1.0
        x[X_ACC_LP] += k * (fn - x[X_ACC_LP])
        x[X_ACC_LP + 1] += k * (fe - x[X_ACC_LP + 1])
        x[X_ACC_LP + 2] += k * (fd - x[X_ACC_LP + 2])
        # history row for fusing late fixes at their time of validity
        i = (int(x[X_HIST_I]) + 1) % H_LEN
        x[X_HIST_I] = i
        x[X_HIST_N] = min(x[X_HIST_N] + 1.0, float(H_LEN))
        hist[i, H_T] = t_s
        hist[i, H_Q] = q0
        hist[i, H_Q + 1] = q1
        hist[i, H_Q + 2] = q2
        hist[i, H_Q + 3] = q3
        hist[i, H_V] = nvn
        hist[i, H_V + 1] = nve
        hist[i, H_V + 2] = nvd
        hist[i, H_LAT] = x[X_LAT]
        hist[i, H_LON] = x[X_LON]
        hist[i, H_H] = x[X_H]
        hist[i, H_W] = wx
        hist[i, H_W + 1] = wy
        hist[i, H_W + 2] = wz

    if x[X_COV_T] >= par[P_COV_PERIOD]:
        epoch = x[X_COV_T]
        propagate_covariance(x, P, par)
        if not nav_ok:
            # unknown velocity/position: keep their block bounded and uncorrelated until a fix sets them
            _reset_block(P, E_V, np.full(3, NAV_UNKNOWN_VAR_V))
            _reset_block(P, E_P, np.full(3, NAV_UNKNOWN_VAR_P))
        if not _aided(x, par):
            flags |= _level(x, P, par, epoch)
        flags |= _mag_update(x, P, par, epoch, math.sqrt(wx * wx + wy * wy + wz * wz))
        _symmetrise(P)
    fill_outputs(x, P, par, wx, wy, wz, out)
    if x[X_WAS_AIDED] > 0.0:
        if x[X_T_LAST] - x[X_GNSS_LAST_T] <= par[P_GNSS_TIMEOUT]:
            flags |= F_GNSS_AIDED
        else:
            flags |= F_GNSS_OUTAGE
    if initialising(x[X_T_RUN], out[O_SIGMA], out[O_SIGMA + 1], out[O_SIGMA + 2], par[P_INIT_TIME],
                    par[P_CONV_TILT], par[P_MAG_ENABLED] > 0.0, par[P_CONV_YAW]):
        flags |= F_INITIALISING
    return flags


@njit(cache=True)
def fill_outputs(x, P, par, wx, wy, wz, out):
    q0 = x[X_Q]
    q1 = x[X_Q + 1]
    q2 = x[X_Q + 2]
    q3 = x[X_Q + 3]
    # magnetic-north frame for the estimate: q_mag = q_z(−declination) ⊗ q_true
    hd = -0.5 * par[P_DECLINATION]
    m0, m1, m2, m3 = quat_mul(math.cos(hd), 0.0, 0.0, math.sin(hd), q0, q1, q2, q3)
    if m0 < 0.0:
        m0, m1, m2, m3 = -m0, -m1, -m2, -m3
    out[O_Q] = m0
    out[O_Q + 1] = m1
    out[O_Q + 2] = m2
    out[O_Q + 3] = m3
    out[O_RATE] = wx
    out[O_RATE + 1] = wy
    out[O_RATE + 2] = wz
    roll, pitch, yaw, sig_roll, sig_pitch = euler_and_tilt_sigma(q0, q1, q2, q3, P[0, 0], P[0, 1], P[1, 1])
    out[O_SIGMA] = sig_roll
    out[O_SIGMA + 1] = sig_pitch
    out[O_SIGMA + 2] = math.sqrt(max(P[2, 2], 0.0))
    out[O_EULER] = roll
    out[O_EULER + 1] = pitch
    out[O_EULER + 2] = yaw
    for i in range(3):
        out[O_BG + i] = x[X_BG + i]
        out[O_BA + i] = x[X_BA + i]
        out[O_VEL + i] = x[X_V + i]
        out[O_SIG_V + i] = math.sqrt(max(P[E_V + i, E_V + i], 0.0))
        out[O_SIG_P + i] = math.sqrt(max(P[E_P + i, E_P + i], 0.0))
    out[O_POS] = x[X_LAT]
    out[O_POS + 1] = x[X_LON]
    out[O_POS + 2] = x[X_H]


# ----------------------------------------------------------------------------------- GNSS fusion
@njit(cache=True)
def _history_at(x, hist, t):
    """Row index pair (older, newer) and weight w of the newer one bracketing time t; (−1, −1, 0) when t is
    older than the history. A t at or after the newest row returns that row."""
    n = int(x[X_HIST_N])
    i = int(x[X_HIST_I])
    if n == 0:
        return -1, -1, 0.0
    if t >= hist[i, H_T]:
        return i, i, 1.0
    for _ in range(n - 1):
        j = (i - 1) % H_LEN
        tj = hist[j, H_T]
        if tj <= t:
            return j, i, (t - tj) / (hist[i, H_T] - tj)
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
    n = int(x[X_HIST_N])
    i = int(x[X_HIST_I])
    for _ in range(n):
        if hist[i, H_T] <= t_from:
            break
        _rotate_attitude(hist[i], H_Q, dx[0], dx[1], dx[2])
        for k in range(3):
            hist[i, H_V + k] += dx[E_V + k]
        hist[i, H_LAT] += dpos_lat
        hist[i, H_LON] += dpos_lon
        hist[i, H_H] += dpos_h
        i = (i - 1) % H_LEN


@njit(cache=True)
def _gated_update(x, P, par, H, nu, var, m, dx, t_fix, i_rej_t0, i_nis, may_reset, r_fused, r_rejected, r_reset):
    """The χ² gate on m rows of one GNSS quantity, then its sequential scalar updates (into dx); on
    rejection, the start of the run of rejections is kept at x[i_rej_t0], and a run spanning P_REJECT_RESET
    asks for a reset (r_reset) when `may_reset`. Returns the R_* bits."""
    nis = _nis(P, H, nu, var, m)
    x[i_nis] = nis
    if nis <= par[P_GATE_CHI2 + m - 1]:
        for i in range(m):
            scalar_update(P, H[i], residual(H[i], nu[i], dx), var[i], 0, dx)
        x[i_rej_t0] = math.nan
        return r_fused
    if math.isnan(x[i_rej_t0]):
        x[i_rej_t0] = t_fix
    elif t_fix - x[i_rej_t0] >= par[P_REJECT_RESET] and may_reset:
        return r_rejected | r_reset
    return r_rejected


@njit(cache=True)
def fuse_gnss(x, P, hist, par, t_fix, lat_fix, lon_fix, alt_fix, vn_fix, ve_fix, vd_fix, sig_h, sig_v, sig_s,
              use_pos, use_alt, use_vel, use_vd):
    """Fuse one GNSS fix (angles in rad, σ in m and m/s) at its time of validity t_fix. Returns R_* bits.

    The innovation is formed against the nominal state interpolated from the history at t_fix (latency) and
    the antenna lever arm: p_ant = p + C r, v_ant = v + C (ω × r). The correction is applied to the current
    state with the current covariance (the error state changes little over the ≤ 1 s of latency). Velocity
    and position are gated separately by the χ² of their normalised innovation; a run of rejections lasting
    P_REJECT_RESET resets that quantity to the fix (a real change, e.g. a receiver that switched to another
    solution) without touching the attitude."""
    res = 0
    if t_fix < x[X_T_LAST] - par[P_MAX_DELAY]:
        return R_TOO_OLD
    j, k, w = _history_at(x, hist, t_fix)
    if j < 0:
        return R_TOO_OLD
    propagate_covariance(x, P, par)
    x[X_LAST_FIX_T] = t_fix
    # the state at the time of validity
    a0 = hist[j, H_Q] * (1.0 - w) + hist[k, H_Q] * w
    a1 = hist[j, H_Q + 1] * (1.0 - w) + hist[k, H_Q + 1] * w
    a2 = hist[j, H_Q + 2] * (1.0 - w) + hist[k, H_Q + 2] * w
    a3 = hist[j, H_Q + 3] * (1.0 - w) + hist[k, H_Q + 3] * w
    a0, a1, a2, a3 = normalised(a0, a1, a2, a3)
    pv = np.zeros(3)
    pw = np.zeros(3)
    for i in range(3):
        pv[i] = hist[j, H_V + i] * (1.0 - w) + hist[k, H_V + i] * w
        pw[i] = hist[j, H_W + i] * (1.0 - w) + hist[k, H_W + i] * w
    plat = hist[j, H_LAT] * (1.0 - w) + hist[k, H_LAT] * w
    plon = hist[j, H_LON] * (1.0 - w) + hist[k, H_LON] * w
    ph = hist[j, H_H] * (1.0 - w) + hist[k, H_H] * w
    on, oe, od, un, ue, ud, c = _lever_terms(a0, a1, a2, a3, pw[0], pw[1], pw[2],
                                             par[P_LEVER], par[P_LEVER + 1], par[P_LEVER + 2])
    r_n, r_e = _radii(par, plat)
    # innovations (fix − prediction), NED
    nu_p = np.zeros(3)
    nu_p[0] = (lat_fix - plat) * (r_n + ph) - on
    nu_p[1] = (lon_fix - plon) * (r_e + ph) * math.cos(plat) - oe
    nu_p[2] = (-(alt_fix - ph) - od) if use_alt else 0.0
    nu_v = np.zeros(3)
    nu_v[0] = vn_fix - pv[0] - un
    nu_v[1] = ve_fix - pv[1] - ue
    nu_v[2] = (vd_fix - pv[2] - ud) if use_vd else 0.0
    var_p = np.array([sig_h * sig_h, sig_h * sig_h, sig_v * sig_v])
    var_v = np.array([sig_s * sig_s, sig_s * sig_s, sig_s * sig_s])
    first = x[X_NAV_OK] <= 0.0
    outage = (not first) and t_fix - x[X_GNSS_LAST_T] > par[P_OUTAGE_RESET]
    if first or outage:
        if not (use_pos and use_vel):
            return res
        # velocity and position from the fix (antenna → IMU), attitude untouched; the shift is also applied
        # to the history so that the next fix compares with the reset trajectory. After an outage the
        # dead-reckoned velocity is metres per second off: fused, that error would be read as tilt all at
        # once (a step of tenths of a degree); reset, the tilt is corrected by the fixes that follow.
        dx = np.zeros(N_ERR)
        for i in range(3):
            dx[E_V + i] = nu_v[i]
            dx[E_P + i] = nu_p[i]
        if not use_vd:
            dx[E_V + 2] = -x[X_V + 2]   # no vertical velocity: assume level motion
        if not use_alt:
            dx[E_P + 2] = 0.0           # 2D fix: keep the height
        for i in range(3):
            x[X_V + i] += dx[E_V + i]
        dlat = dx[E_P] / (r_n + ph)
        dlon = dx[E_P + 1] / ((r_e + ph) * math.cos(plat))
        x[X_LAT] += dlat
        x[X_LON] += dlon
        x[X_H] -= dx[E_P + 2]
        _reset_block(P, E_V, var_v if use_vd else np.array([var_v[0], var_v[1], 1.0]))
        _reset_block(P, E_P, var_p if use_alt else np.array([var_p[0], var_p[1], NAV_UNKNOWN_VAR_P]))
        # the tilt so far came from levelling, which leans by the unknown acceleration (a turn: a/g); its
        # small variance would make the GNSS read that lean as accelerometer bias: widen it
        st2 = par[P_NAV_INIT_TILT] ** 2 if first or t_fix - x[X_GNSS_LAST_T] > par[P_DEAD_RECKON] else 0.0
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
        x[X_NAV_OK] = 1.0
        x[X_WAS_AIDED] = 1.0
        x[X_GNSS_LAST_T] = t_fix
        x[X_VEL_REJ_T0] = math.nan
        x[X_POS_REJ_T0] = math.nan
        return R_NAV_INIT if first else R_OUTAGE_RESET

    lx = par[P_LEVER]
    ly = par[P_LEVER + 1]
    lz = par[P_LEVER + 2]
    dx = np.zeros(N_ERR)
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
    m_v = 3 if use_vd else 2
    if use_vel:
        # a velocity reset needs the positions to disagree too (or none): a receiver whose velocity
        # contradicts its own positions is wrong, not the filter
        may_reset = not use_pos or not math.isnan(x[X_POS_REJ_T0])
        res |= _gated_update(x, P, par, hv, nu_v, var_v, m_v, dx, t_fix, X_VEL_REJ_T0, X_NIS_V, may_reset,
                             R_VEL_FUSED, R_VEL_REJECTED, R_VEL_RESET)
    m_p = 3 if use_alt else 2
    if use_pos:
        res |= _gated_update(x, P, par, hp, nu_p, var_p, m_p, dx, t_fix, X_POS_REJ_T0, X_NIS_P, True,
                             R_POS_FUSED, R_POS_REJECTED, R_POS_RESET)
    _symmetrise(P)
    lat_before = x[X_LAT]
    lon_before = x[X_LON]
    h_before = x[X_H]
    _apply_correction(x, par, dx)
    dlat = x[X_LAT] - lat_before
    dlon = x[X_LON] - lon_before
    dh = x[X_H] - h_before
    # resets after a persistent change: the quantity jumps to the fix, attitude untouched
    if res & R_VEL_RESET:
        for i in range(m_v):
            x[X_V + i] += nu_v[i] - dx[E_V + i]
            dx[E_V + i] = nu_v[i]
        _reset_block(P, E_V, var_v)
        x[X_VEL_REJ_T0] = math.nan
    if res & R_POS_RESET:
        extra_lat = (nu_p[0] - dx[E_P]) / (r_n + ph)
        extra_lon = (nu_p[1] - dx[E_P + 1]) / ((r_e + ph) * math.cos(plat))
        extra_h = -(nu_p[2] - dx[E_P + 2]) if use_alt else 0.0
        x[X_LAT] += extra_lat
        x[X_LON] += extra_lon
        x[X_H] += extra_h
        dlat += extra_lat
        dlon += extra_lon
        dh += extra_h
        _reset_block(P, E_P, var_p)
        x[X_POS_REJ_T0] = math.nan
    _correct_history(hist, x, t_fix, dx, dlat, dlon, dh)
    if res & (R_VEL_FUSED | R_POS_FUSED | R_VEL_RESET | R_POS_RESET):
        x[X_GNSS_LAST_T] = t_fix
    return res


def fast_step(example_args):
    """`ins_step` compiled for the types of `example_args` (one call) and returned as that overload's directly
    callable entry point (skips numba's per-call type dispatch, as mekf_core.fast_step does); falls back to the
    dispatcher."""
    ins_step(*example_args)
    try:
        return ins_step.overloads[tuple(ins_step.typeof_pyval(a) for a in example_args)].entry_point
    except Exception:  # pragma: no cover - numba internals moved
        pass
    return ins_step  # pragma: no cover
