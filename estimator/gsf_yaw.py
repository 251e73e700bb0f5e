"""A magnetometer-free GNSS yaw: a Gaussian-sum bank of small EKFs (the EKF-GSF of ArduPilot and PX4), compiled.

What it estimates: the **true** yaw of the body (ZYX Euler yaw, body FRD → true-north NED) from the IMU and the
GNSS horizontal velocity alone, with a variance that includes the spread between the hypotheses, and whether
that yaw is usable ("valid"). References: ArduPilot `libraries/AP_NavEKF/EKFGSF_yaw.cpp`, PX4
`src/modules/ekf2/EKF/yaw_estimator/EKFGSF_yaw.cpp` (re-derived here, not copied); `../shared/anchors/
heading-integrity.md` §1, §6, §7.

The bank: `n_models` (default 5) models, model i started at yaw −180° + 360°·(i + ½)/n with a yaw σ of half
the spacing. Each model has

* its own tilt AHRS: a body→NED rotation matrix propagated with the summed gyro increments and pulled towards
  the measured vertical by a complementary gain (AP/PX4: 0.2 /s), where the measured vertical is the specific
  force **minus the body's kinematic acceleration** with the velocity along body x: a = (V̇, ω_z V, −ω_y V), V the
  GNSS speed (less the antenna's lever-arm velocity). This is ArduPilot's TAS term (0, r·TAS, −q·TAS) with the
  GNSS speed for the TAS and V̇ added, so the tilt stays right in coordinated turns, braking and climbs. It does
  not depend on the model's yaw, on purpose: subtracting the GNSS NED acceleration rotated into the body with
  each model's own attitude lets every model tilt its yaw error away on the AHRS time constant (a wrong yaw's
  misdirected acceleration becomes a tilt, and the model predicts the GNSS velocity as well as the right one),
  so a bank started in a steady turn settled confidently wrong (15° off at σ 2°: docs/estimator.md). The price
  is the no-sideslip assumption: a slip angle β (tyres, a boat's leeway and current, wind drift) leaves ω·V·β
  forward and V̇·β sideways, which the bias states below absorb and `sideslip_sigma_rad` keeps in their variance;
* a 5-state EKF x = [v_N, v_E, ψ, b_f, b_r] (`MODEL_STATE_NAMES`): horizontal velocity (m/s), yaw (rad) and a
  horizontal specific-force bias in the level heading frame (front, right; m/s²). The velocity is predicted
  with the AHRS's horizontal velocity increment, v ← v + Rz(ψ)(Δv_h − b Δt). The bias states are the
  steady-turn fix (anchor §7): in a steady turn the body-frame acceleration is constant, so a yaw error δψ is
  indistinguishable from a forward specific-force error δψ·a_lat (an accelerometer bias, or the slip above);
  with the bias states the filter keeps σψ ≈ σ_b / a_lat there instead of collapsing, and only a change of turn
  rate or speed, or turns both ways, separate them.

The Gaussian sum: after each fused fix, w_i ← w_i · N(ν_i; 0, S_i), normalised (log domain), floored at
`weight_floor`; composite yaw = atan2(Σ w sin ψ, Σ w cos ψ), composite variance = Σ w (P_ψψ + wrap(ψ_i − ψ̄)²).

Timing: `gsf_accumulate_imu` (every IMU sample) only sums Δθ and ΔV (ΔV rotated into the interval's first body
frame to first order); the bank predicts once `predict_interval_s` has accumulated. A ring of the bank's past
predicted antenna velocities lets `gsf_fuse_velocity` form each model's innovation against its prediction at
the fix's time of validity (up to `max_fix_delay_s` old); the correction is applied to the current state and
shifts the ring's stored velocities by the same amount, so a later fix valid before this one is not fused
against stale predictions.

Levelling (`_align_tilt`, after a reset without a tilt): on the specific force less the same kinematic
acceleration, once that is within 10 % of g. Before the first GNSS speed that acceleration is unknown and taken
as zero; the first fix then measures the lean this levelling took (`_lean_unchecked`: the angle between f and
f − a) and, beyond `relevel_min_lean_rad` (5°, a one-interval levelling's 1σ), the bank levels again on
f − a. ArduPilot and PX4 level on the raw force within 0.9–1.1 g: a restart in a coordinated turn
banked up to 25° levels on the bank angle, a harder one waits and levels on a leaning force in the roll-out,
and the hypotheses then fit their velocities through a tilt tens of degrees off while it converges at 0.2 /s:
a plane restarted in a 29° turn was valid and 179° off at σ 5–9° (docs/estimator.md "bank39").

Validity (`state.valid`), re-evaluated at every prediction step: all of
  1. composite σ < `sigma_valid_max_rad` (AP/PX4: 15°);
  2. ≥ `valid_fixes_required` consecutive fused fixes whose σ and weighted velocity innovation
     (< `max_vel_innov_m_s`, AP 2 m/s) passed (AP: 5), and ≥ `min_active_s` since the bank (re)started (PX4 10 s);
  3. a manoeuvre seen recently: the horizontal acceleration from differenced GNSS velocities, low-passed over
     `manoeuvre_tau_s`, stayed above `manoeuvre_accel_m_s2` for `manoeuvre_min_s`, and that ended at most
     `stale_after_s` ago. This is what ages the validity on straight constant-speed legs, where the GNSS says
     nothing about yaw (σ itself grows only with the gyro's residual errors there);
  4. a fix fused within `max_fix_gap_s` (no stale validity after a GNSS loss: AP #15651).

Resets (`gsf_reset`): at start, on request, and when `reset_after_rejected_fixes` consecutive fixes were
rejected because every model's innovation exceeded `innov_clip_sigma` (no hypothesis explains the data: a
diverged bank). A single such fix (a GNSS glitch) is rejected and counted, nothing else. After a fix gap longer
than `max_fix_gap_s` the velocities are re-seeded from the next fix (yaws and weights kept) and the persistence
count restarts.

Units: SI, angles rad, body FRD, NED; the gyro and accelerometer given to it are bias-corrected (the `ins`
supplies its estimates: for the gyro, the last bias this bank's yaw confirmed, never one a magnetometer alone
taught, `Ins._monitor_decision`); the bank does not learn a gyro bias itself. It assumes forward motion (a reversing
vehicle turns the no-sideslip term's sign). The state and the parameters are numpy structured records (numba
Records): named fields, no index tables; `P[i]` is model i's 5×5 covariance in the order `MODEL_STATE_NAMES`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
from numba import njit

from ahrsd.core.gnss import GnssFix

from .kernel_rotations import set_dcm_from_euler

MODEL_STATE_NAMES = ("vel_n", "vel_e", "yaw", "bias_front", "bias_right")
_VN, _VE, _YAW, _BF, _BR = (MODEL_STATE_NAMES.index(n) for n in MODEL_STATE_NAMES)
N_MODEL_STATES = len(MODEL_STATE_NAMES)
RING_LEN = 64                   # past predictions kept for delayed fixes: RING_LEN · predict_interval_s of history
STANDARD_GRAVITY_M_S2 = 9.80665
_TWO_PI = 2.0 * math.pi

# outcome of gsf_fuse_velocity
FUSED = 0
SEEDED = 1          # velocities (re)set from this fix (first fix, or after a gap); no weight update
REJECTED_CLIPPED = 2    # every model's innovation beyond innov_clip_sigma: not fused (a glitch, or a diverged bank)
REJECTED_TOO_OLD = 3    # valid before the oldest stored prediction
REJECTED_BAD_INPUT = 4  # non-finite velocity or σ
WAITING_FOR_TILT = 5    # the AHRS tilt is not aligned yet (no accelerometer data near 1 g)


@dataclass(frozen=True)
class GsfParams:
    """Tuning of the GSF yaw estimator. SI units, angles in rad."""

    n_models: int = 5
    """Yaw hypotheses in the bank (AP/PX4: 5)."""
    predict_interval_s: float = 0.01
    """The bank predicts when this much IMU time has accumulated."""
    accel_noise_m_s2_rthz: float = 0.3
    """Horizontal specific-force error as white noise (AHRS tilt noise, vibration, unmodelled lever-arm and
    sculling), m/s²/√Hz: the velocity variance grows by its square per second."""
    yaw_rate_noise_rad_s_rthz: float = 0.003
    """Yaw random walk (residual gyro bias, noise), rad/√s."""
    yaw_rate_scale_sqrt_s: float = 0.01
    """Yaw process noise proportional to the yaw rate (gyro scale and misalignment residue): (this·|ψ̇|)² per
    second, √s."""
    accel_bias_sigma_m_s2: float = 0.1
    """Prior 1σ of each horizontal specific-force bias state (accelerometer bias residue plus g × AHRS tilt
    error), m/s²."""
    accel_bias_walk_m_s2_rts: float = 0.003
    """Random walk of the bias states, m/s²/√s."""
    vel_sigma_floor_m_s: float = 0.15
    """Floor of the GNSS velocity 1σ used (receivers understate it; AP floors at 0.5, PX4 at 0.01), m/s."""
    innov_clip_sigma: float = 5.0
    """Innovations beyond this many σ are scaled down to it (AP/PX4: 5); when every model's is, the fix is
    rejected."""
    weight_floor: float = 1e-5
    """Smallest model weight after normalisation (a model can recover)."""
    tilt_gain_per_s: float = 0.2
    """AHRS tilt correction gain, 1/s (AP/PX4: 0.2)."""
    tilt_align_gain_per_s: float = 1.0
    """... during the first `tilt_align_s` after a reset, 1/s."""
    tilt_align_s: float = 5.0
    relevel_min_lean_rad: float = math.radians(5.0)
    """A levelling made before any GNSS speed is done again at the first fix when the kinematic acceleration the
    fix's speed tells leaned it by more than this (`_lean_unchecked`): the 1σ of a levelling from one interval
    of the specific force (what the `ins` states at a start and levels again beyond, estimator/ins_start.py
    `first_fix_in_turn`); a smaller lean is within what the fast tilt gain removes while a wave's or a bump's
    acceleration in that one interval would make levelling again no better."""
    speed_rate_tau_s: float = 0.2
    """Low-pass time constant of the rate of change of the GNSS speed (the tilt AHRS's longitudinal
    acceleration), s."""
    sideslip_sigma_rad: float = math.radians(5.0)
    """1σ of the angle between the body x axis and the velocity over ground (a car's tyre slip, a boat's leeway
    and current, a plane's wind drift). The tilt AHRS assumes it zero; its effect, ω·V·β forward and V̇·β
    sideways, is kept in the bias states' variance, so in a steady turn σψ cannot fall below about this."""
    manoeuvre_tau_s: float = 2.0
    """Low-pass time constant of the horizontal acceleration (differenced GNSS velocities) the manoeuvre
    detector looks at (differenced velocity noise must not look like a manoeuvre), s."""
    manoeuvre_accel_m_s2: float = 0.3
    """A manoeuvre: that low-passed horizontal acceleration above this (PX4 EKF2_MAG_ACCLIM 0.5; lower here
    for a boat's 0.5 m/s² turns)..."""
    manoeuvre_min_s: float = 1.0
    """... sustained this long, s."""
    stale_after_s: float = 30.0
    """Valid only while the last manoeuvre ended at most this long ago, s."""
    sigma_valid_max_rad: float = math.radians(15.0)
    """Valid only below this composite σ (AP GSF_YAW_ACCURACY_THRESHOLD_DEG, PX4 EKFGSF_yaw_err_max)."""
    max_vel_innov_m_s: float = 2.0
    """A fix counts towards validity only when the weighted velocity innovation is shorter (AP maxYawEstVelInnov)."""
    valid_fixes_required: int = 5
    """Consecutive passing fixes before valid (AP GSF_YAW_VALID_HISTORY_THRESHOLD)."""
    min_active_s: float = 10.0
    """Time since the (re)start before valid (PX4 EKFGSF_min_active_time after an in-air restart), s."""
    max_fix_gap_s: float = 1.0
    """Longer without a fused fix: not valid; the next fix re-seeds the velocities, s."""
    max_fix_delay_s: float = 0.5
    """Fixes valid longer ago than this (or than the ring holds) are rejected, s."""
    reset_after_rejected_fixes: int = 5
    """Consecutive all-models-clipped fixes that restart the bank."""
    lever_arm_m: tuple = (0.0, 0.0, 0.0)
    """GNSS antenna position from the IMU, body FRD, m: the antenna velocity is v + C (ω × r)."""

    def to_record(self):
        """The parameters as a GSF_PARAMS_DTYPE record (what the kernels take)."""
        if self.n_models < 2:
            raise ValueError("n_models must be ≥ 2")
        if not 0.0 < self.predict_interval_s <= 0.1:
            raise ValueError("predict_interval_s must be in (0, 0.1] s")
        if self.max_fix_delay_s >= RING_LEN * self.predict_interval_s:
            raise ValueError("max_fix_delay_s must be shorter than the prediction ring "
                             f"({RING_LEN} × predict_interval_s)")
        rec = np.zeros(1, dtype=GSF_PARAMS_DTYPE).view(np.recarray)[0]
        for f in fields(self):
            rec[f.name] = np.asarray(getattr(self, f.name), dtype=float) if f.name == "lever_arm_m" \
                else getattr(self, f.name)
        return rec


GSF_PARAMS_DTYPE = np.dtype(
    [(f.name, np.float64, (3,)) if f.name == "lever_arm_m" else
     (f.name, np.int64 if f.type in (int, "int") else np.float64) for f in fields(GsfParams)], align=True)
DEFAULT_GSF_PARAMS = GsfParams()


def gsf_state_dtype(n_models: int = 5) -> np.dtype:
    """The bank's state record for `n_models` models (see the module docstring for the fields' meaning)."""
    n = int(n_models)
    return np.dtype([
        # per model: EKF
        ("weight", np.float64, (n,)),
        ("vel_ne_m_s", np.float64, (n, 2)),
        ("yaw_rad", np.float64, (n,)),
        ("accel_bias_m_s2", np.float64, (n, 2)),       # level heading frame: front, right
        ("P", np.float64, (n, N_MODEL_STATES, N_MODEL_STATES)),
        ("innov_m_s", np.float64, (n, 2)),             # last fix's innovation (antenna velocity)
        ("test_ratio", np.float64, (n,)),              # νᵀS⁻¹ν of the last fix, before clipping
        ("clipped", np.uint8, (n,)),                # 1: innovation beyond innov_clip_sigma
        # per model: tilt AHRS
        ("dcm", np.float64, (n, 3, 3)),                # body → NED
        # ring of past predicted antenna velocities (delayed fixes)
        ("ring_t_s", np.float64, (RING_LEN,)),
        ("ring_vel_ne_m_s", np.float64, (RING_LEN, n, 2)),
        ("ring_next", np.int64),
        ("ring_count", np.int64),
        # IMU accumulation since the last prediction
        ("t_s", np.float64),                           # time of the newest IMU sample
        ("acc_dt_s", np.float64),
        ("acc_dtheta_rad", np.float64, (3,)),
        ("acc_dvel_m_s", np.float64, (3,)),
        ("rate_rad_s", np.float64, (3,)),              # body rate over the last prediction interval
        ("force_m_s2", np.float64, (3,)),              # specific force over the last prediction interval
        # GNSS bookkeeping
        ("have_prev_fix", np.bool_),
        ("prev_fix_t_s", np.float64),
        ("prev_fix_vel_ned_m_s", np.float64, (3,)),
        ("prev_fix_has_down", np.bool_),
        ("prev_fix_arm_x_m_s", np.float64),
        ("last_fused_t_s", np.float64),
        ("speed_m_s", np.float64),                     # GNSS speed (3-D when the fix has a down velocity)
        ("speed_rate_m_s2", np.float64),               # its low-passed rate of change
        ("manoeuvre_accel_ne_m_s2", np.float64, (2,)),  # the detector's low-passed horizontal acceleration
        ("manoeuvre_run_s", np.float64),               # how long the kinematic acceleration has been high
        ("last_manoeuvre_t_s", np.float64),            # NaN: none since the reset
        # status
        ("tilt_aligned", np.bool_),
        ("tilt_without_speed", np.bool_),              # levelled before any GNSS speed: its lean is unchecked
        ("vel_seeded", np.bool_),
        ("reset_t_s", np.float64),
        ("n_passing_fixes", np.int64),                 # consecutive
        ("n_rejected_in_row", np.int64),
        ("n_rejected", np.int64),
        ("n_fused", np.int64),
        ("n_resets", np.int64),
        ("n_clipped", np.int64),                       # models clipped at the last fused fix
        ("vel_innov_m_s", np.float64),                 # weighted innovation length of the last fused fix
        ("valid", np.bool_),
    ], align=True)


GSF_STATE_DTYPE = gsf_state_dtype(DEFAULT_GSF_PARAMS.n_models)


def new_gsf_state(params: GsfParams = DEFAULT_GSF_PARAMS, t_s: float = 0.0):
    """A reset bank (record of gsf_state_dtype(params.n_models)) whose clock reads `t_s` (the time of the
    sample before the first one accumulated); tilt levelled from the first accelerometer data."""
    st = np.zeros(1, dtype=gsf_state_dtype(params.n_models)).view(np.recarray)[0]
    gsf_reset(st, params.to_record(), float(t_s), np.full(4, np.nan))
    st.n_resets = 0
    return st


# ----------------------------------------------------------------------------------------- small maths
@njit(cache=True)
def _wrap(a):
    return (a + math.pi) % _TWO_PI - math.pi


@njit(cache=True)
def _rotate_dcm_body(c, rx, ry, rz):
    """c ← c · exp([r×]) (Rodrigues), then re-orthonormalised."""
    ang2 = rx * rx + ry * ry + rz * rz
    if ang2 < 1e-12:
        a, b = 1.0 - ang2 / 6.0, 0.5 - ang2 / 24.0
    else:
        ang = math.sqrt(ang2)
        a, b = math.sin(ang) / ang, (1.0 - math.cos(ang)) / ang2
    # E = I + a K + b K², K = [r×]
    e00 = 1.0 - b * (ry * ry + rz * rz)
    e11 = 1.0 - b * (rx * rx + rz * rz)
    e22 = 1.0 - b * (rx * rx + ry * ry)
    e01 = -a * rz + b * rx * ry
    e10 = a * rz + b * rx * ry
    e02 = a * ry + b * rx * rz
    e20 = -a * ry + b * rx * rz
    e12 = -a * rx + b * ry * rz
    e21 = a * rx + b * ry * rz
    for i in range(3):
        c0, c1, c2 = c[i, 0], c[i, 1], c[i, 2]
        c[i, 0] = c0 * e00 + c1 * e10 + c2 * e20
        c[i, 1] = c0 * e01 + c1 * e11 + c2 * e21
        c[i, 2] = c0 * e02 + c1 * e12 + c2 * e22
    _orthonormalise(c)


@njit(cache=True)
def _orthonormalise(c):
    """Symmetric first-order re-orthonormalisation of the columns x, y; z = x × y."""
    err = 0.5 * (c[0, 0] * c[0, 1] + c[1, 0] * c[1, 1] + c[2, 0] * c[2, 1])
    x0, x1, x2 = c[0, 0] - err * c[0, 1], c[1, 0] - err * c[1, 1], c[2, 0] - err * c[2, 1]
    y0, y1, y2 = c[0, 1] - err * c[0, 0], c[1, 1] - err * c[1, 0], c[2, 1] - err * c[2, 0]
    nx = 1.0 / math.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
    ny = 1.0 / math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
    x0, x1, x2 = x0 * nx, x1 * nx, x2 * nx
    y0, y1, y2 = y0 * ny, y1 * ny, y2 * ny
    c[0, 0], c[1, 0], c[2, 0] = x0, x1, x2
    c[0, 1], c[1, 1], c[2, 1] = y0, y1, y2
    c[0, 2], c[1, 2], c[2, 2] = x1 * y2 - x2 * y1, x2 * y0 - x0 * y2, x0 * y1 - x1 * y0


@njit(cache=True)
def _rotate_dcm_yaw(c, dpsi):
    """c ← Rz(dpsi) · c (a yaw change about NED down, tilt kept)."""
    cs, sn = math.cos(dpsi), math.sin(dpsi)
    for j in range(3):
        a, b = c[0, j], c[1, j]
        c[0, j] = cs * a - sn * b
        c[1, j] = sn * a + cs * b


@njit(cache=True)
def _dcm_yaw(c):
    return math.atan2(c[1, 0], c[0, 0])


# ----------------------------------------------------------------------------------------- reset
@njit(cache=True)
def gsf_reset(state, params, t_s, tilt_q_wxyz):
    """Restart the bank at time `t_s`: weights equal, yaws evenly spread over ±180° with σ = half the spacing,
    velocities unknown until the next fix seeds them, biases at their prior. The tilt comes from `tilt_q_wxyz`
    (body → NED; its yaw is ignored) or, when its first element is NaN, from the next accelerometer data near
    1 g. Validity, persistence and manoeuvre history restart; the IMU accumulation and the GNSS kinematic
    acceleration are kept."""
    n = state.weight.shape[0]
    spacing = _TWO_PI / n
    have_tilt = not math.isnan(tilt_q_wxyz[0])
    roll = pitch = 0.0
    if have_tilt:
        q0, q1, q2, q3 = tilt_q_wxyz[0], tilt_q_wxyz[1], tilt_q_wxyz[2], tilt_q_wxyz[3]
        roll = math.atan2(2.0 * (q0 * q1 + q2 * q3), 1.0 - 2.0 * (q1 * q1 + q2 * q2))
        pitch = math.asin(min(1.0, max(-1.0, 2.0 * (q0 * q2 - q3 * q1))))
    for i in range(n):
        state.weight[i] = 1.0 / n
        state.yaw_rad[i] = -math.pi + spacing * (i + 0.5)
        state.vel_ne_m_s[i, 0] = 0.0
        state.vel_ne_m_s[i, 1] = 0.0
        state.accel_bias_m_s2[i, 0] = 0.0
        state.accel_bias_m_s2[i, 1] = 0.0
        for j in range(N_MODEL_STATES):
            for k in range(N_MODEL_STATES):
                state.P[i, j, k] = 0.0
        state.P[i, _VN, _VN] = 100.0
        state.P[i, _VE, _VE] = 100.0
        state.P[i, _YAW, _YAW] = (0.5 * spacing) ** 2
        state.P[i, _BF, _BF] = params.accel_bias_sigma_m_s2 ** 2
        state.P[i, _BR, _BR] = params.accel_bias_sigma_m_s2 ** 2
        state.innov_m_s[i, 0] = 0.0
        state.innov_m_s[i, 1] = 0.0
        state.test_ratio[i] = 0.0
        state.clipped[i] = 0
        set_dcm_from_euler(state.dcm[i], state.yaw_rad[i], pitch, roll)
    state.ring_next = 0
    state.ring_count = 0
    state.t_s = t_s
    state.tilt_aligned = have_tilt
    state.tilt_without_speed = False
    state.vel_seeded = False
    state.reset_t_s = t_s
    state.last_fused_t_s = np.nan
    state.manoeuvre_run_s = 0.0
    state.last_manoeuvre_t_s = np.nan
    state.n_passing_fixes = 0
    state.n_rejected_in_row = 0
    state.n_clipped = 0
    state.vel_innov_m_s = 0.0
    state.valid = False
    state.n_resets += 1


# ----------------------------------------------------------------------------------------- prediction
@njit(cache=True)
def gsf_accumulate_imu(state, params, dt_s, gyro_rad_s, accel_m_s2):
    """Add one IMU sample (bias-corrected gyro rad/s and specific force m/s², body FRD, held over `dt_s`); the
    bank predicts once `predict_interval_s` has accumulated. Non-finite or non-positive input is skipped; a step
    over 0.1 s moves the clock without integrating."""
    gsf_accumulate_imu_xyz(state, params, dt_s, gyro_rad_s[0], gyro_rad_s[1], gyro_rad_s[2],
                           accel_m_s2[0], accel_m_s2[1], accel_m_s2[2])


@njit(cache=True)
def gsf_accumulate_imu_xyz(state, params, dt_s, gx_rad_s, gy_rad_s, gz_rad_s, ax_m_s2, ay_m_s2, az_m_s2):
    """`gsf_accumulate_imu` with the components as scalars: no array to build per sample in a compiled caller."""
    if not dt_s > 0.0:
        return
    if dt_s > 0.1:
        # a gap in the samples: the clock moves on, the gap is not integrated
        state.t_s += dt_s
        return
    gx, gy, gz = gx_rad_s * dt_s, gy_rad_s * dt_s, gz_rad_s * dt_s
    ax, ay, az = ax_m_s2 * dt_s, ay_m_s2 * dt_s, az_m_s2 * dt_s
    if not (math.isfinite(gx + gy + gz) and math.isfinite(ax + ay + az)):
        return
    th = state.acc_dtheta_rad
    dv = state.acc_dvel_m_s
    # ΔV of this sample into the interval's first body frame: (I + [θ×]) Δv, θ the rotation so far (first order)
    dv[0] += ax + th[1] * az - th[2] * ay
    dv[1] += ay + th[2] * ax - th[0] * az
    dv[2] += az + th[0] * ay - th[1] * ax
    th[0] += gx
    th[1] += gy
    th[2] += gz
    state.acc_dt_s += dt_s
    state.t_s += dt_s
    if state.acc_dt_s >= params.predict_interval_s - 1e-9:
        _predict(state, params)


@njit(cache=True)
def _predict(state, params):
    """One prediction of every model over the accumulated interval: tilt AHRS, EKF, and the ring entry."""
    dt = state.acc_dt_s
    th = state.acc_dtheta_rad
    dvb = state.acc_dvel_m_s
    n = state.weight.shape[0]
    state.rate_rad_s[0] = th[0] / dt
    state.rate_rad_s[1] = th[1] / dt
    state.rate_rad_s[2] = th[2] / dt
    fx, fy, fz = dvb[0] / dt, dvb[1] / dt, dvb[2] / dt
    state.force_m_s2[0] = fx
    state.force_m_s2[1] = fy
    state.force_m_s2[2] = fz
    acc_x, acc_y, acc_z = _kinematic_acceleration(state)
    # the measured vertical less the kinematic acceleration, the same for every model
    ux, uy, uz = fx - acc_x, fy - acc_y, fz - acc_z
    if not state.tilt_aligned:
        _align_tilt(state, ux, uy, uz)
        _clear_accumulators(state)
        return
    gain = params.tilt_align_gain_per_s if state.t_s - state.reset_t_s < params.tilt_align_s \
        else params.tilt_gain_per_s
    lx, ly, lz = params.lever_arm_m[0], params.lever_arm_m[1], params.lever_arm_m[2]
    wx, wy, wz = state.rate_rad_s[0], state.rate_rad_s[1], state.rate_rad_s[2]
    # ω × r: the antenna's velocity relative to the IMU, body frame
    arm_x, arm_y, arm_z = wy * lz - wz * ly, wz * lx - wx * lz, wx * ly - wy * lx
    slot = state.ring_next
    state.ring_t_s[slot] = state.t_s
    for i in range(n):
        c = state.dcm[i]
        # horizontal velocity increment from this model's attitude at the start of the interval
        dvn = c[0, 0] * dvb[0] + c[0, 1] * dvb[1] + c[0, 2] * dvb[2]
        dve = c[1, 0] * dvb[0] + c[1, 1] * dvb[1] + c[1, 2] * dvb[2]
        yaw_before = _dcm_yaw(c)
        _tilt_ahrs_step(c, th, ux, uy, uz, gain, dt)
        yaw_after = _dcm_yaw(c)
        state.yaw_rad[i] = yaw_after
        _ekf_predict(state, params, i, dvn, dve, yaw_before, _wrap(yaw_after - yaw_before), dt, acc_y)
        # the ring holds the antenna's predicted velocity
        state.ring_vel_ne_m_s[slot, i, 0] = state.vel_ne_m_s[i, 0] + \
            c[0, 0] * arm_x + c[0, 1] * arm_y + c[0, 2] * arm_z
        state.ring_vel_ne_m_s[slot, i, 1] = state.vel_ne_m_s[i, 1] + \
            c[1, 0] * arm_x + c[1, 1] * arm_y + c[1, 2] * arm_z
    state.ring_next = (slot + 1) % RING_LEN
    if state.ring_count < RING_LEN:
        state.ring_count += 1
    _clear_accumulators(state)
    _update_validity(state, params)


@njit(cache=True)
def _align_tilt(state, ux, uy, uz):
    """Level every model's attitude (roll, pitch; yaws kept) on the specific force less the kinematic acceleration
    (`_kinematic_acceleration`: what the tilt AHRS takes for the vertical) once that is within 10 % of g. Before any
    GNSS speed the kinematic acceleration is taken as zero and the levelling is marked unchecked
    (`_lean_unchecked`): in a turn the specific force g_up + ω × v leans by atan(|ω × v|/g), 20–30° in a hard one,
    and a raw-force gate (ArduPilot's and PX4's 0.9–1.1 g) lets a lean of up to 25° through, or waits out the turn
    and levels on it later at the slow gain."""
    f_norm = math.sqrt(ux * ux + uy * uy + uz * uz)
    if abs(f_norm - STANDARD_GRAVITY_M_S2) < 0.1 * STANDARD_GRAVITY_M_S2:
        roll = math.atan2(-uy, -uz)
        pitch = math.atan2(ux, math.sqrt(uy * uy + uz * uz))
        for i in range(state.weight.shape[0]):
            set_dcm_from_euler(state.dcm[i], state.yaw_rad[i], pitch, roll)
        state.tilt_aligned = True
        state.tilt_without_speed = not state.have_prev_fix


@njit(cache=True, inline="always")
def _kinematic_acceleration(state):
    """The body's kinematic acceleration with the velocity along body x (no sideslip), speed V from the GNSS:
    a = d/dt (V x̂) + ω × V x̂ = (V̇, ω_z V, −ω_y V). It does not depend on any model's yaw, so no model can
    explain its yaw error away by tilting (ArduPilot's TAS term, plus V̇, with the GNSS speed for TAS)."""
    speed = max(0.0, state.speed_m_s + state.speed_rate_m_s2 * (state.t_s - state.prev_fix_t_s)) \
        if state.have_prev_fix else 0.0
    return state.speed_rate_m_s2, state.rate_rad_s[2] * speed, -state.rate_rad_s[1] * speed


@njit(cache=True, inline="always")
def _tilt_ahrs_step(c, th, ux, uy, uz, gain, dt):
    """Rotate one model's body → NED matrix `c` by the gyro increment `th` plus the tilt correction towards the
    measured vertical (u = f − a, the specific force less the kinematic acceleration)."""
    # measured down = −u/|u|, estimated down = Cᵀ ẑ (row 2 of C);
    # δθ = k Δt (down_meas × down_est) turns the estimate towards the measurement (tilt only: ⟂ down)
    un = math.sqrt(ux * ux + uy * uy + uz * uz)
    cx = cy = cz = 0.0
    if un > 0.0:
        # gain fades to zero where |f − Cᵀa| is 0.5 g or 1.5 g (AP/PX4 fade the uncorrected |f| the same way)
        fade = max(0.0, 1.0 - 2.0 * abs(un / STANDARD_GRAVITY_M_S2 - 1.0))
        k = gain * dt * fade / un
        mx, my, mz = -ux * k, -uy * k, -uz * k
        ex, ey, ez = c[2, 0], c[2, 1], c[2, 2]
        cx, cy, cz = my * ez - mz * ey, mz * ex - mx * ez, mx * ey - my * ex
    _rotate_dcm_body(c, th[0] + cx, th[1] + cy, th[2] + cz)


@njit(cache=True, inline="always")
def _ekf_predict(state, params, i, dvn, dve, yaw_before, dpsi, dt, acc_y):
    """Model i's EKF prediction: v ← v + Δv_h − Rz(ψ) b Δt (ψ follows the AHRS: dpsi), P ← F P Fᵀ + Q, with
    the bias variance floored at what the no-sideslip assumption can get wrong (`acc_y` = ω_z V, the forward
    error ω V β; V̇ β sideways)."""
    q_vel = params.accel_noise_m_s2_rthz ** 2 * dt
    q_bias = params.accel_bias_walk_m_s2_rts ** 2 * dt
    q_yaw_white = params.yaw_rate_noise_rad_s_rthz ** 2 * dt
    bias_floor_f = (acc_y * params.sideslip_sigma_rad) ** 2
    bias_floor_r = (state.speed_rate_m_s2 * params.sideslip_sigma_rad) ** 2
    cs, sn = math.cos(yaw_before), math.sin(yaw_before)
    bf, br = state.accel_bias_m_s2[i, 0], state.accel_bias_m_s2[i, 1]
    net_n = dvn - (cs * bf - sn * br) * dt
    net_e = dve - (sn * bf + cs * br) * dt
    state.vel_ne_m_s[i, 0] += net_n
    state.vel_ne_m_s[i, 1] += net_e
    # F = I + ∂/∂ψ (column yaw) + ∂/∂b (columns bias)
    f_vn_yaw, f_ve_yaw = -net_e, net_n
    f_vn_bf, f_ve_bf = -cs * dt, -sn * dt
    f_vn_br, f_ve_br = sn * dt, -cs * dt
    p = state.P[i]
    # rows: FP (only rows vel_n, vel_e change)
    for j in range(N_MODEL_STATES):
        p[_VN, j] += f_vn_yaw * p[_YAW, j] + f_vn_bf * p[_BF, j] + f_vn_br * p[_BR, j]
        p[_VE, j] += f_ve_yaw * p[_YAW, j] + f_ve_bf * p[_BF, j] + f_ve_br * p[_BR, j]
    # columns: (FP)Fᵀ
    for j in range(N_MODEL_STATES):
        p[j, _VN] += f_vn_yaw * p[j, _YAW] + f_vn_bf * p[j, _BF] + f_vn_br * p[j, _BR]
        p[j, _VE] += f_ve_yaw * p[j, _YAW] + f_ve_bf * p[j, _BF] + f_ve_br * p[j, _BR]
    p[_VN, _VN] += q_vel
    p[_VE, _VE] += q_vel
    p[_YAW, _YAW] += q_yaw_white + (params.yaw_rate_scale_sqrt_s * dpsi) ** 2 / dt
    p[_BF, _BF] = max(p[_BF, _BF] + q_bias, bias_floor_f)
    p[_BR, _BR] = max(p[_BR, _BR] + q_bias, bias_floor_r)


@njit(cache=True)
def _clear_accumulators(state):
    state.acc_dt_s = 0.0
    for j in range(3):
        state.acc_dtheta_rad[j] = 0.0
        state.acc_dvel_m_s[j] = 0.0


# ----------------------------------------------------------------------------------------- output
@njit(cache=True)
def _composite(state):
    n = state.weight.shape[0]
    s = c = 0.0
    for i in range(n):
        s += state.weight[i] * math.sin(state.yaw_rad[i])
        c += state.weight[i] * math.cos(state.yaw_rad[i])
    yaw = math.atan2(s, c)
    var = 0.0
    for i in range(n):
        d = _wrap(state.yaw_rad[i] - yaw)
        var += state.weight[i] * (state.P[i, _YAW, _YAW] + d * d)
    return yaw, math.sqrt(var)


@njit(cache=True)
def gsf_output(state):
    """(yaw rad (true, ZYX), σ rad, valid, models clipped at the last fused fix)."""
    yaw, sigma = _composite(state)
    return yaw, sigma, state.valid, state.n_clipped


@njit(cache=True)
def gsf_output_of(states):
    """`gsf_output` of the bank held as a 1-element state array: an array argument is unboxed for a call from
    Python several times faster than a record (ins reads it at every fix)."""
    return gsf_output(states[0])


@njit(cache=True)
def _update_validity(state, params):
    _, sigma = _composite(state)
    t = state.t_s
    ok = sigma < params.sigma_valid_max_rad
    ok = ok and state.n_passing_fixes >= params.valid_fixes_required
    ok = ok and t - state.reset_t_s >= params.min_active_s
    ok = ok and not math.isnan(state.last_manoeuvre_t_s) and t - state.last_manoeuvre_t_s <= params.stale_after_s
    ok = ok and not math.isnan(state.last_fused_t_s) and t - state.last_fused_t_s <= params.max_fix_gap_s
    state.valid = ok


# ----------------------------------------------------------------------------------------- fusion
@njit(cache=True)
def _gnss_kinematics(state, params, t_s, vn, ve, vd, has_down):
    """From successive fixes: the IMU's speed and its low-passed rate (the tilt AHRS's kinematic acceleration)
    and the low-passed horizontal acceleration that detects manoeuvres."""
    # the antenna's speed less its lever-arm velocity along body x (where the no-sideslip model puts the velocity)
    w = state.rate_rad_s
    arm_x = w[1] * params.lever_arm_m[2] - w[2] * params.lever_arm_m[1]
    if state.have_prev_fix:
        dt = t_s - state.prev_fix_t_s
        if dt <= 0.0:
            return
        pv = state.prev_fix_vel_ned_m_s
        down = has_down and state.prev_fix_has_down
        speed = math.sqrt(vn * vn + ve * ve + (vd * vd if down else 0.0)) - arm_x
        speed0 = math.sqrt(pv[0] * pv[0] + pv[1] * pv[1] + (pv[2] * pv[2] if down else 0.0)) - state.prev_fix_arm_x_m_s
        md = state.manoeuvre_accel_ne_m_s2
        if dt <= 1.0:
            a = min(1.0, dt / params.speed_rate_tau_s)
            state.speed_rate_m_s2 += a * ((speed - speed0) / dt - state.speed_rate_m_s2)
            b = min(1.0, dt / params.manoeuvre_tau_s)
            md[0] += b * ((vn - pv[0]) / dt - md[0])
            md[1] += b * ((ve - pv[1]) / dt - md[1])
            if math.hypot(md[0], md[1]) >= params.manoeuvre_accel_m_s2:
                state.manoeuvre_run_s += dt
                if state.manoeuvre_run_s >= params.manoeuvre_min_s:
                    state.last_manoeuvre_t_s = t_s
            else:
                state.manoeuvre_run_s = 0.0
        else:
            state.speed_rate_m_s2 = 0.0
            md[0] = 0.0
            md[1] = 0.0
            state.manoeuvre_run_s = 0.0
    state.speed_m_s = math.sqrt(vn * vn + ve * ve + (vd * vd if has_down else 0.0)) - arm_x
    state.prev_fix_arm_x_m_s = arm_x
    state.have_prev_fix = True
    state.prev_fix_t_s = t_s
    state.prev_fix_vel_ned_m_s[0] = vn
    state.prev_fix_vel_ned_m_s[1] = ve
    state.prev_fix_vel_ned_m_s[2] = vd
    state.prev_fix_has_down = has_down


@njit(cache=True)
def _predicted_at(state, t_s, i):
    """Model i's predicted antenna velocity at `t_s` from the ring (linear between stored steps; the newest when
    `t_s` is later). Returns (ok, v_n, v_e); not ok when `t_s` is before the oldest entry."""
    cnt = state.ring_count
    newest = (state.ring_next - 1) % RING_LEN
    if t_s >= state.ring_t_s[newest]:
        return True, state.ring_vel_ne_m_s[newest, i, 0], state.ring_vel_ne_m_s[newest, i, 1]
    k = newest
    for _ in range(cnt - 1):
        prev = (k - 1) % RING_LEN
        t0 = state.ring_t_s[prev]
        if t0 <= t_s:
            t1 = state.ring_t_s[k]
            u = (t_s - t0) / (t1 - t0) if t1 > t0 else 1.0
            v0n, v0e = state.ring_vel_ne_m_s[prev, i, 0], state.ring_vel_ne_m_s[prev, i, 1]
            return True, v0n + u * (state.ring_vel_ne_m_s[k, i, 0] - v0n), \
                v0e + u * (state.ring_vel_ne_m_s[k, i, 1] - v0e)
        k = prev
    return False, 0.0, 0.0


@njit(cache=True)
def _shift_velocity(state, i, dvn, dve):
    """Model i's velocity moved by (dvn, dve), and its stored predictions with it, so an older fix still to
    come is compared with predictions that include this correction (not fused twice)."""
    state.vel_ne_m_s[i, 0] += dvn
    state.vel_ne_m_s[i, 1] += dve
    for k in range(state.ring_count):
        slot = (state.ring_next - 1 - k) % RING_LEN
        state.ring_vel_ne_m_s[slot, i, 0] += dvn
        state.ring_vel_ne_m_s[slot, i, 1] += dve


@njit(cache=True)
def gsf_fuse_velocity(state, params, t_s, vel_ne_m_s, vel_sigma_m_s):
    """Fuse a GNSS velocity valid at `t_s` (IMU clock; up to `max_fix_delay_s` behind the newest sample).
    `vel_ne_m_s`: true-north NED velocity of the antenna, m/s — (N, E) or (N, E, D); a finite D also feeds the
    vertical kinematic acceleration used by the tilt AHRS. `vel_sigma_m_s`: the receiver's 1σ speed accuracy
    (floored at `vel_sigma_floor_m_s`). Returns an outcome code (FUSED, SEEDED, REJECTED_*, WAITING_FOR_TILT)."""
    vn, ve = vel_ne_m_s[0], vel_ne_m_s[1]
    has_down = vel_ne_m_s.shape[0] > 2 and math.isfinite(vel_ne_m_s[2])
    vd = vel_ne_m_s[2] if has_down else 0.0
    if not (math.isfinite(vn) and math.isfinite(ve) and math.isfinite(t_s)) or not vel_sigma_m_s >= 0.0:
        state.n_rejected += 1
        return REJECTED_BAD_INPUT
    if state.t_s - t_s > params.max_fix_delay_s:
        state.n_rejected += 1
        return REJECTED_TOO_OLD
    if not state.tilt_aligned or state.ring_count == 0:
        _gnss_kinematics(state, params, t_s, vn, ve, vd, has_down)
        return WAITING_FOR_TILT
    r = max(vel_sigma_m_s, params.vel_sigma_floor_m_s) ** 2
    gap = math.isnan(state.last_fused_t_s) or t_s - state.last_fused_t_s > params.max_fix_gap_s
    if not state.vel_seeded or gap:
        _gnss_kinematics(state, params, t_s, vn, ve, vd, has_down)
        if state.tilt_without_speed and _lean_unchecked(state, params):
            return WAITING_FOR_TILT
        _seed_velocities(state, t_s, vn, ve, r)
        return SEEDED
    clip2 = params.innov_clip_sigma ** 2
    n_clipped = _innovations(state, t_s, vn, ve, r, clip2)
    if n_clipped < 0:
        state.n_rejected += 1
        return REJECTED_TOO_OLD
    if n_clipped == state.weight.shape[0]:
        _reject_unexplained(state, params, t_s, vn, ve, vd, has_down)
        return REJECTED_CLIPPED
    state.n_rejected_in_row = 0
    # the speed and manoeuvre bookkeeping take only fixes some hypothesis explains (not a glitch)
    _gnss_kinematics(state, params, t_s, vn, ve, vd, has_down)
    vel_innov_m_s = _weighted_innovation_m_s(state)
    _update_models(state, params, r, clip2)
    _count_fused(state, params, t_s, n_clipped, vel_innov_m_s)
    _update_validity(state, params)
    return FUSED


@njit(cache=True)
def gsf_fuse_velocity_of(states, params, t_s, vel_ne_m_s, vel_sigma_m_s):
    """`gsf_fuse_velocity` of the bank and its parameters held as 1-element arrays (as `gsf_output_of`)."""
    return gsf_fuse_velocity(states[0], params[0], t_s, vel_ne_m_s, vel_sigma_m_s)


@njit(cache=True)
def _lean_unchecked(state, params):
    """The first GNSS speed after a levelling made without one: how far did the kinematic acceleration it took as
    zero lean the vertical? u = f − a with a = (V̇, ω_z V, −ω_y V) at the newest interval's force and rate; the
    angle between f and u is the levelling's tilt error. Beyond `relevel_min_lean_rad` the bank levels again at
    its next prediction, on u, its ring
    emptied (its predictions were made at the leaned tilt). Returns True when it levels again (the fix is not
    used: the next one seeds the velocities)."""
    state.tilt_without_speed = False
    fx, fy, fz = state.force_m_s2[0], state.force_m_s2[1], state.force_m_s2[2]
    ax, ay, az = _kinematic_acceleration(state)
    ux, uy, uz = fx - ax, fy - ay, fz - az
    # |f × u| / (|f| |u|) = sin of the angle between them
    cx, cy, cz = fy * uz - fz * uy, fz * ux - fx * uz, fx * uy - fy * ux
    nf = math.sqrt(fx * fx + fy * fy + fz * fz)
    nu = math.sqrt(ux * ux + uy * uy + uz * uz)
    if not (nf > 0.0 and nu > 0.0):
        return False
    sin_lean = math.sqrt(cx * cx + cy * cy + cz * cz) / (nf * nu)
    if sin_lean <= math.sin(params.relevel_min_lean_rad):
        return False
    state.tilt_aligned = False
    state.ring_count = 0
    state.ring_next = 0
    return True


@njit(cache=True)
def _seed_velocities(state, t_s, vn, ve, r):
    """(Re)seed: each model's velocity moved by its innovation against its prediction at t_s (the stored
    predictions too), variance `r` from the fix's accuracy; yaw and weights kept, no weight update."""
    n = state.weight.shape[0]
    for i in range(n):
        ok, pn, pe = _predicted_at(state, t_s, i)
        if not ok:
            newest = (state.ring_next - 1) % RING_LEN
            pn, pe = state.ring_vel_ne_m_s[newest, i, 0], state.ring_vel_ne_m_s[newest, i, 1]
        _shift_velocity(state, i, vn - pn, ve - pe)
        for j in range(N_MODEL_STATES):
            state.P[i, _VN, j] = 0.0
            state.P[i, j, _VN] = 0.0
            state.P[i, _VE, j] = 0.0
            state.P[i, j, _VE] = 0.0
        state.P[i, _VN, _VN] = r
        state.P[i, _VE, _VE] = r
    state.vel_seeded = True
    state.last_fused_t_s = t_s
    state.n_passing_fixes = 0


@njit(cache=True)
def _innovations(state, t_s, vn, ve, r, clip2):
    """Each model's innovation against its prediction at t_s and its normalised square νᵀS⁻¹ν, stored in the
    state (innov_m_s, test_ratio, clipped: beyond `clip2`). Returns how many models are clipped, or −1 when
    t_s is older than the stored predictions."""
    n = state.weight.shape[0]
    n_clipped = 0
    for i in range(n):
        ok, pn, pe = _predicted_at(state, t_s, i)
        if not ok:
            return -1
        nu_n, nu_e = vn - pn, ve - pe
        p = state.P[i]
        s00, s01, s11 = p[_VN, _VN] + r, p[_VN, _VE], p[_VE, _VE] + r
        det = s00 * s11 - s01 * s01
        ratio = (s11 * nu_n * nu_n - 2.0 * s01 * nu_n * nu_e + s00 * nu_e * nu_e) / det
        state.innov_m_s[i, 0] = nu_n
        state.innov_m_s[i, 1] = nu_e
        state.test_ratio[i] = ratio
        state.clipped[i] = 1 if ratio > clip2 else 0
        if state.clipped[i] == 1:
            n_clipped += 1
    return n_clipped


@njit(cache=True)
def _reject_unexplained(state, params, t_s, vn, ve, vd, has_down):
    """No model explains the fix (every innovation clipped): counted and not fused; `reset_after_rejected_fixes`
    of these in a row restart the bank (a diverged bank rather than a glitch)."""
    state.n_rejected += 1
    state.n_rejected_in_row += 1
    state.n_passing_fixes = 0
    if state.n_rejected_in_row >= params.reset_after_rejected_fixes:
        q = np.full(4, np.nan)
        gsf_reset(state, params, state.t_s, q)
        _gnss_kinematics(state, params, t_s, vn, ve, vd, has_down)


@njit(cache=True)
def _weighted_innovation_m_s(state):
    """Length of the weight-averaged innovation (unclipped) of the models (validity's max_vel_innov_m_s)."""
    inn_n = inn_e = 0.0
    for i in range(state.weight.shape[0]):
        inn_n += state.weight[i] * state.innov_m_s[i, 0]
        inn_e += state.weight[i] * state.innov_m_s[i, 1]
    return math.hypot(inn_n, inn_e)


@njit(cache=True)
def _update_models(state, params, r, clip2):
    """Every model's EKF update with its stored innovation (innovation at the fix's time, correction now),
    then the Gaussian-sum weights from the innovations' likelihoods."""
    n = state.weight.shape[0]
    log_w = np.empty(n)
    for i in range(n):
        log_w[i] = _update_model(state, i, r, clip2)
    _reweight(state, params, log_w)


@njit(cache=True)
def _update_model(state, i, r, clip2):
    """Model i's EKF update with its innovation (clipped to `clip2` in νᵀS⁻¹ν); returns its log weight times
    the innovation's likelihood, log w_i − ½ νᵀS⁻¹ν − ½ log det S (2π is common to all)."""
    nu_n, nu_e = state.innov_m_s[i, 0], state.innov_m_s[i, 1]
    ratio = state.test_ratio[i]
    if ratio > clip2:
        scale = math.sqrt(clip2 / ratio)
        nu_n *= scale
        nu_e *= scale
        ratio = clip2
    p = state.P[i]
    s00, s01, s11 = p[_VN, _VN] + r, p[_VN, _VE], p[_VE, _VE] + r
    det = s00 * s11 - s01 * s01
    i00, i01, i11 = s11 / det, -s01 / det, s00 / det
    # K = P Hᵀ S⁻¹ (H picks vel_n, vel_e); x += K ν; P −= K H P
    kx = np.empty((N_MODEL_STATES, 2))
    for j in range(N_MODEL_STATES):
        kx[j, 0] = p[j, _VN] * i00 + p[j, _VE] * i01
        kx[j, 1] = p[j, _VN] * i01 + p[j, _VE] * i11
    hp_n = p[_VN].copy()
    hp_e = p[_VE].copy()
    for j in range(N_MODEL_STATES):
        for k in range(N_MODEL_STATES):
            p[j, k] -= kx[j, 0] * hp_n[k] + kx[j, 1] * hp_e[k]
    for j in range(N_MODEL_STATES):
        for k in range(j + 1, N_MODEL_STATES):
            m = 0.5 * (p[j, k] + p[k, j])
            p[j, k] = m
            p[k, j] = m
        p[j, j] = max(p[j, j], 1e-9)
    dvn = kx[_VN, 0] * nu_n + kx[_VN, 1] * nu_e
    dve = kx[_VE, 0] * nu_n + kx[_VE, 1] * nu_e
    dpsi = kx[_YAW, 0] * nu_n + kx[_YAW, 1] * nu_e
    _shift_velocity(state, i, dvn, dve)
    state.accel_bias_m_s2[i, 0] += kx[_BF, 0] * nu_n + kx[_BF, 1] * nu_e
    state.accel_bias_m_s2[i, 1] += kx[_BR, 0] * nu_n + kx[_BR, 1] * nu_e
    state.yaw_rad[i] = _wrap(state.yaw_rad[i] + dpsi)
    _rotate_dcm_yaw(state.dcm[i], dpsi)
    return math.log(max(state.weight[i], 1e-300)) - 0.5 * ratio - 0.5 * math.log(det)


@njit(cache=True)
def _reweight(state, params, log_w):
    """w_i ← exp(log_w_i) normalised (in the log domain: the largest subtracted first), floored at
    `weight_floor` and normalised again."""
    n = state.weight.shape[0]
    best = -np.inf
    for i in range(n):
        if log_w[i] > best:
            best = log_w[i]
    total = 0.0
    for i in range(n):
        log_w[i] = math.exp(log_w[i] - best)
        total += log_w[i]
    total2 = 0.0
    for i in range(n):
        w = max(log_w[i] / total, params.weight_floor)
        state.weight[i] = w
        total2 += w
    for i in range(n):
        state.weight[i] /= total2


@njit(cache=True)
def _count_fused(state, params, t_s, n_clipped, vel_innov_m_s):
    """The bookkeeping of a fused fix: counts, and the run of passing fixes validity needs (composite σ and
    weighted innovation below their limits)."""
    state.n_clipped = n_clipped
    state.n_fused += 1
    state.last_fused_t_s = t_s
    state.vel_innov_m_s = vel_innov_m_s
    _, sigma = _composite(state)
    if sigma < params.sigma_valid_max_rad and state.vel_innov_m_s < params.max_vel_innov_m_s:
        state.n_passing_fixes += 1
    else:
        state.n_passing_fixes = 0


# ----------------------------------------------------------------------------------------- Python wrapper
class GsfYaw:
    """The bank for tests, replay and benches: feed IMU samples (or arrays of them) and GNSS fixes.

    `update_imu(sample)` takes an `ImuSample` (its gyro and accelerometer: give them bias-corrected) or
    `update_imu(t_s, gyro_rad_s, accel_m_s2)` with arrays (n,) / (n, 3), fed one by one through the compiled
    accumulator; `update_gnss(fix)` takes a `GnssFix` (its `t_s` is the time of validity on the IMU clock, its
    `vel_ned_m_s` true NED, its `s_acc_m_s` the speed accuracy)."""

    def __init__(self, params: GsfParams = DEFAULT_GSF_PARAMS):
        self.params = params
        self._par = params.to_record()
        self.state = np.zeros(1, dtype=gsf_state_dtype(params.n_models)).view(np.recarray)[0]
        self._started = False

    def reset(self, tilt_q_wxyz=None):
        q = np.full(4, np.nan) if tilt_q_wxyz is None else np.asarray(tilt_q_wxyz, dtype=float)
        gsf_reset(self.state, self._par, float(self.state.t_s), q)

    def update_imu(self, sample_or_t, gyro_rad_s=None, accel_m_s2=None):
        if gyro_rad_s is None:
            s = sample_or_t
            t = np.array([s.t_s], dtype=float)
            g = np.asarray(s.gyro_rad_s, dtype=float).reshape(1, 3)
            a = np.asarray(s.accel_m_s2, dtype=float).reshape(1, 3)
        else:
            t = np.atleast_1d(np.asarray(sample_or_t, dtype=float))
            g = np.asarray(gyro_rad_s, dtype=float).reshape(-1, 3)
            a = np.asarray(accel_m_s2, dtype=float).reshape(-1, 3)
        if not self._started:
            if len(t) < 1:
                return
            # the clock starts at the first sample (which is only the clock's origin)
            gsf_reset(self.state, self._par, float(t[0]), np.full(4, np.nan))
            self.state.n_resets = 0
            self._started = True
        _feed(self.state, self._par, t, np.ascontiguousarray(g), np.ascontiguousarray(a))

    def update_gnss(self, fix: GnssFix) -> int:
        """Fuse a fix's velocity; returns the outcome code. Fixes before the first IMU sample are ignored."""
        if not self._started:
            return WAITING_FOR_TILT
        v = np.asarray(fix.vel_ned_m_s, dtype=float)
        s_acc = float(fix.s_acc_m_s)
        if not math.isfinite(s_acc):
            s_acc = 0.0
        return int(gsf_fuse_velocity(self.state, self._par, float(fix.t_s), v, s_acc))

    @property
    def output(self):
        yaw, sigma, valid, n_clipped = gsf_output(self.state)
        return float(yaw), float(sigma), bool(valid), int(n_clipped)

    @property
    def yaw_rad(self) -> float:
        return self.output[0]

    @property
    def sigma_rad(self) -> float:
        return self.output[1]

    @property
    def valid(self) -> bool:
        return bool(self.state.valid)


@njit(cache=True)
def _feed(state, params, t_s, gyro, accel):
    """Accumulate samples at times t_s (the step to each from the clock's previous time)."""
    for k in range(t_s.shape[0]):
        dt = t_s[k] - state.t_s
        gsf_accumulate_imu(state, params, dt, gyro[k], accel[k])


__all__ = ["GsfParams", "DEFAULT_GSF_PARAMS", "GSF_PARAMS_DTYPE", "GSF_STATE_DTYPE", "gsf_state_dtype",
           "MODEL_STATE_NAMES", "new_gsf_state", "gsf_reset", "gsf_accumulate_imu", "gsf_accumulate_imu_xyz",
           "gsf_fuse_velocity",
           "gsf_output", "GsfYaw", "FUSED", "SEEDED", "REJECTED_CLIPPED", "REJECTED_TOO_OLD",
           "REJECTED_BAD_INPUT", "WAITING_FOR_TILT"]
