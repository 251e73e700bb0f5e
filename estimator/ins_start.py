"""How `ins` starts its kernel's state from one sample, or restarts it after a gap keeping what it had learned:
the attitude levelled on the accelerometer with the magnetometer's heading (initial_attitude.py, turned to true
north), the state record cleared, the sensor errors started (zero, or the learned ones over a restart), the
history's first row, the magnetometer check's reference field, and the start-up covariance.

Each function is told the arrays it writes (the filter's state record, covariance and history, ins_core's dtypes)
and the figures it starts them with; none keeps anything. What runs beside the kernel (the GNSS yaw bank, the
queued fixes, the published heading, the biases a yaw reset goes back to) is started again by the filter.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Protocol

import numpy as np

from ahrsd.core.angles import STANDARD_GRAVITY_M_S2

from . import ins_core as core
from .initial_attitude import initial_attitude
from .rotations import quat_conjugate, quat_multiply, quat_normalize, quat_to_dcm
from .yaw_reset import restart_uncorrelated


class StartSigmas(Protocol):
    """The start-up 1σ's the covariance is built from (InsParams has them)."""

    init_sigma_tilt_rad: float
    init_sigma_yaw_rad: float
    calibration_sigma_rad: float        # the magnetometer calibration's heading error (InsParams's property)
    init_gyro_bias_sigma_rad_s: float
    init_accel_bias_sigma_m_s2: float
    init_gyro_scale_sigma: float
    init_gyro_misalignment_sigma_rad: float
    accel_axes_tilt_sigma_rad: float


class LearnedErrors(NamedTuple):
    """What a restart after a gap keeps (copies taken before the state is cleared): the sensor errors learned and
    the magnetometer check's state (its reference field); zeros and None at the first start."""

    gyro_bias_rad_s: np.ndarray
    accel_bias_m_s2: np.ndarray
    gyro_scale: np.ndarray
    gyro_misalignment_rad: np.ndarray
    mag_check: np.void | None


def initial_true_attitude(a, m, declination_rad: float) -> np.ndarray:
    """The levelled attitude (heading from m, or 0 without it: initial_attitude.py) turned from magnetic to
    the filter's frame, true north: q_true = q_z(declination) ⊗ q_mag."""
    q_mag = initial_attitude(a, m)
    hd = 0.5 * declination_rad
    w, x_, y, z = q_mag
    c, s = math.cos(hd), math.sin(hd)
    return np.array([c * w - s * z, c * x_ - s * y, c * y + s * x_, c * z + s * w])


class StartLean(NamedTuple):
    """How far levelling on the start's one sample may be off (`levelling_lean`)."""

    lean_rad: float     # the largest angle between the specific force and the vertical its norm allows
    dip_rad: float      # the field's dip measured against that specific force (NaN without a field)


def levelling_lean(a, m, tolerance_m_s2: float) -> StartLean:
    """Levelling takes the specific force f for "up"; f = g_up + a with the vehicle's acceleration a, which in a
    steady turn is the horizontal centripetal ω × v. A horizontal a leans f from the vertical by atan(|a|/g) =
    acos(g/|f|) (a coordinated turn: |f| = g/cos(bank)); that is the largest lean the norm allows while a has no
    vertical part, and taken as 0 while |f| is within `tolerance_m_s2` (the levelling's noise on the specific
    force) of g. g is the standard one (the filter's before it knows where it is).
    Levelling on the accelerometer assumes the vehicle unaccelerated (Titterton & Weston, Strapdown Inertial
    Navigation Technology, 2nd ed., the chapter on alignment)."""
    f = np.asarray(a, dtype=float)
    fn = float(np.linalg.norm(f))
    lean = math.acos(STANDARD_GRAVITY_M_S2 / fn) if fn > STANDARD_GRAVITY_M_S2 + tolerance_m_s2 else 0.0
    dip = math.nan
    if m is not None and np.all(np.isfinite(m)) and fn > 0.0:
        mv = np.asarray(m, dtype=float)
        mn = float(np.linalg.norm(mv))
        if mn > 0.0:
            dip = math.asin(min(max(-float(np.dot(f / fn, mv / mn)), -1.0), 1.0))
    return StartLean(lean, dip)


def levelling_force(a, g_rad_s, tolerance_m_s2: float, rate_sigma_rad_s: float) -> np.ndarray:
    """The specific force to level on: `a` itself, or in a steady turn its part along the rotation axis.

    A vehicle in a steady level turn (a car's circle, an aircraft's coordinated turn) rotates about the local
    vertical, so the gyro's rate vector is the vertical, and the centripetal ω × v is perpendicular to it: the
    specific force's component along the axis is g and the rest is the turn's. When that holds within
    `tolerance_m_s2` (the levelling's noise on the specific force), the specific force leans further from the
    axis than that noise allows, and further than the axis itself may be off (3 `rate_sigma_rad_s`, the gyro
    bias's 1σ, across the rate), the axis part is the better vertical; a boat rolling, a vehicle at rest or
    driving straight has its rate about another axis (or only noise) and fails the test."""
    f = np.asarray(a, dtype=float)
    w = np.asarray(g_rad_s, dtype=float)
    wn = float(np.linalg.norm(w))
    if not (wn > 0.0 and np.all(np.isfinite(w))):
        return f
    along = float(np.dot(f, w / wn))
    if abs(abs(along) - STANDARD_GRAVITY_M_S2) > tolerance_m_s2:
        return f
    across = float(np.linalg.norm(f - along * w / wn))
    if across <= tolerance_m_s2 or math.atan2(3.0 * rate_sigma_rad_s, wn) >= math.atan2(across, abs(along)):
        return f
    return along * w / wn


def first_fix_lean(q, rate_rad_s, vel_ned_m_s, f_m_s2) -> float:
    """How far a tilt levelled on the specific force may be off, told at the first fix: the vehicle's
    acceleration leans f from the vertical, and in a turn that acceleration is the centripetal ω × v (ω the rate
    in the navigation frame, v the fix's velocity), horizontal, which leans f by atan(|ω × v|/g); the part of it
    that is not horizontal shows as |f| departing from g, which leans it by up to ||f| − g|/g more. A rate along
    the velocity (a boat rolling) has no centripetal part. g is the standard one."""
    c = np.asarray(quat_to_dcm(q), dtype=float)
    w_n = c @ np.asarray(rate_rad_s, dtype=float)
    centripetal = float(np.linalg.norm(np.cross(w_n, np.asarray(vel_ned_m_s, dtype=float))))
    fn = float(np.linalg.norm(np.asarray(f_m_s2, dtype=float)))
    return math.atan2(centripetal, STANDARD_GRAVITY_M_S2) + abs(fn - STANDARD_GRAVITY_M_S2) / STANDARD_GRAVITY_M_S2


def centripetal_levelling_force(a, rate_rad_s, speed_m_s: float) -> np.ndarray | None:
    """The specific force less a turn's centripetal acceleration, told at the first fix: a vehicle that moves
    along its forward (body x) axis at `speed_m_s` while it rotates at ω (body) feels ω × v with v = speed·x̂,
    and f − ω × v is gravity's reaction alone, the vertical to level on (what ArduPilot's DCM does with the
    airspeed or GNSS speed on a vehicle that flies forward). None when taking it away does not bring |f| nearer
    g: the vehicle does not move forward (reversing, a boat's drift) or the rest of f is not the turn's."""
    f = np.asarray(a, dtype=float)
    w = np.asarray(rate_rad_s, dtype=float)
    if not (np.all(np.isfinite(f)) and np.all(np.isfinite(w)) and speed_m_s > 0.0):
        return None
    fc = f - np.cross(w, np.array([speed_m_s, 0.0, 0.0]))
    g = STANDARD_GRAVITY_M_S2
    if not abs(float(np.linalg.norm(fc)) - g) < abs(float(np.linalg.norm(f)) - g):
        return None
    return fc


def widen_for_lean(P: np.ndarray, lean_rad: float) -> bool:
    """A start levelled on the specific force, at its first fix: the tilt 1σ at least the `lean_rad` the fix
    tells (`first_fix_lean`), restarted uncorrelated (as `initial_covariance`). Levelling updates before the fix
    took the lean for the vertical, so they do not know it: without this the GNSS velocity, fused through a
    confident wrong yaw, pulls the tilt further off. The magnetometer's yaw, read at that tilt, is off by the
    tilt's error through the dip: the filter couples it to the tilt after this (`couple_yaw_to_tilt`), which
    puts tan(dip)·lean into its 1σ, correlated with the tilt. True when it widened."""
    if not lean_rad > math.sqrt(max(P[core.E_TILT_N, core.E_TILT_N], P[core.E_TILT_E, core.E_TILT_E])):
        return False
    for i in (core.E_TILT_N, core.E_TILT_E):
        restart_uncorrelated(P, i, lean_rad ** 2)
    return True


def tilt_through_dip_row(q, m) -> np.ndarray | None:
    """How a tilt error tips the magnetometer's heading: the yaw error δθ_D per tilt error (δθ_N, δθ_E) of a yaw set
    from the field m (body) at the attitude q, (Z/H)·u with u the horizontal field's direction and Z/H = tan(dip)
    (the field (mn, me, md) in the estimated NED frame: Z/H·u = md·(mn, me)/(mn² + me²)). The kernel's heading row
    (ins_core `_mag_heading_row`) is α = −δθ_D + (Z/H) u·δθ; a yaw taken where α = 0 is off by (Z/H) u·δθ_tilt: a
    6.3° tilt about the horizontal field's axis at a −72° dip puts the heading about 19° off (docs/estimator.md
    "startsig"). None without a horizontal field."""
    mv = np.asarray(m, dtype=float)
    if not np.all(np.isfinite(mv)):
        return None
    mn, me, md = np.asarray(quat_to_dcm(q), dtype=float) @ mv
    mh2 = float(mn * mn + me * me)
    if not mh2 > 0.0:
        return None
    return np.array([md * mn / mh2, md * me / mh2])


def couple_yaw_to_tilt(P: np.ndarray, row: np.ndarray) -> None:
    """The magnetometer set the yaw at a tilt the levelling could not check: its error is the field's heading error
    plus `row`·δθ_tilt (`tilt_through_dip_row`). The yaw's error state taken to that, δθ_D' = δθ_D + row·δθ_tilt,
    is the linear map A (the identity, and `row` in the yaw's row at the tilt's columns): P ← A P Aᵀ (Maybeck,
    Stochastic Models, Estimation and Control vol. 1, covariance of a linear function of a random vector). It puts
    row P_tt rowᵀ into the yaw's variance and row·P_tt into its covariance with the tilt, so that what later
    corrects the tilt (the fixes' velocity) corrects the yaw with it, and the heading row that carries the tilt
    (ins_core `_mag_heading_row` once fixes hold the tilt) reads the yaw's error as the tilt's."""
    tilt = (core.E_TILT_N, core.E_TILT_E)
    a = np.eye(P.shape[0])
    a[core.E_YAW, tilt[0]] = row[0]
    a[core.E_YAW, tilt[1]] = row[1]
    P[:] = a @ P @ a.T


def axis_levelling_sigma_rad(rate_rad_s, rate_sigma_rad_s: float) -> float:
    """How far a vertical levelled on the rotation axis (`levelling_force`) may be off per horizontal axis: the
    gyro's bias across the rate, 1σ `rate_sigma_rad_s` per axis, tips the measured axis by atan(σ_b/|ω|)."""
    wn = float(np.linalg.norm(np.asarray(rate_rad_s, dtype=float)))
    return math.atan2(rate_sigma_rad_s, wn) if wn > 0.0 else math.pi / 2.0


def level_again(x: np.void, P: np.ndarray, hist: np.ndarray, p: StartSigmas, f_level, m, declination_rad: float) -> None:
    """The attitude levelled on `f_level` with the magnetometer's heading (as at the start), the history rows
    turned with it (the fixes that follow compare with them), the tilt and yaw restarted uncorrelated at the
    start's 1σ (the tilt at least what |f_level| still departs from g by, over g)."""
    q_old = np.asarray(x["q"], dtype=float).copy()
    q_new = initial_true_attitude(f_level, m, declination_rad)
    turn = quat_multiply(q_new, quat_conjugate(q_old))
    for k in range(int(x["hist_count"])):
        i = (int(x["hist_newest"]) - k) % hist.shape[0]
        hist[i]["q"] = quat_normalize(quat_multiply(turn, hist[i]["q"]))
    x["q"] = q_new
    c = np.asarray(quat_to_dcm(q_new), dtype=float)
    x["acc_ned_lp_m_s2"] = c @ x["acc_last_m_s2"]
    # levelled on the force, the attitude saw no horizontal acceleration over the fix's delay
    carry_over_fix_delay(x)
    residual = abs(float(np.linalg.norm(f_level)) - STANDARD_GRAVITY_M_S2) / STANDARD_GRAVITY_M_S2
    for i in (core.E_TILT_N, core.E_TILT_E):
        restart_uncorrelated(P, i, max(p.init_sigma_tilt_rad, residual) ** 2)
    restart_uncorrelated(P, core.E_YAW, max(p.init_sigma_yaw_rad, p.calibration_sigma_rad) ** 2)


def carry_over_fix_delay(x: np.void) -> None:
    """The first fix set the velocity it had at its own time, which is this sample's less the fix's delay
    (`t_last_s` − `gnss_fused_t_s`; 0.095 s in the simulator): carried over that delay as the turn turns it, the
    horizontal velocity rotated about the vertical by the rate about it (the down row of C times the gyro less its
    bias) times the delay, the centripetal ω × v (0.3–0.6 m/s in 0.095 s in the restarts of docs/estimator.md
    "bank39"). Not C f: its horizontal part turns with the start's yaw, which the magnetometer gives through the
    levelled tilt's error at the dip (20° off at Hobart from a 6.3° tilt error), and a centripetal turned 20° puts
    1.3 m/s² along the track; the carry then made the next fixes fail the velocity gate (docs/estimator.md
    "bank2"). The rate about the vertical does not depend on the yaw."""
    delay_s = float(x["t_last_s"]) - float(x["gnss_fused_t_s"])
    if 0.0 < delay_s < math.inf:
        c = np.asarray(quat_to_dcm(x["q"]), dtype=float)
        rate_down_rad_s = float(c[2] @ (np.asarray(x["gyro_last_rad_s"], dtype=float)
                                        - np.asarray(x["gyro_bias_rad_s"], dtype=float)))
        turn_rad = rate_down_rad_s * delay_s
        v_n, v_e = float(x["vel_ned_m_s"][0]), float(x["vel_ned_m_s"][1])
        x["vel_ned_m_s"][0] = math.cos(turn_rad) * v_n - math.sin(turn_rad) * v_e
        x["vel_ned_m_s"][1] = math.sin(turn_rad) * v_n + math.cos(turn_rad) * v_e


def first_fix_in_turn(x: np.void, P: np.ndarray, hist: np.ndarray, p: StartSigmas, declination_rad: float,
                      yaw_from_mag: bool, may_level_again: bool = True) -> bool:
    """The first fix of a start levelled on the specific force (x the state just after it set the velocity): in a
    turn that force leaned by the centripetal ω × v, which the fix's speed now tells. Levelled again on the force
    less it (`centripetal_levelling_force`, `level_again`) when that explains the force's norm, moves the vertical
    by more than the tilt 1σ, the magnetometer gives the heading at the new tilt and `may_level_again` (the
    attitude is still the start's); otherwise the tilt 1σ widened to the lean it cannot exclude (`first_fix_lean`,
    `widen_for_lean`; the filter then couples the magnetometer's yaw to it). True when the attitude was levelled
    again."""
    rate = x["gyro_last_rad_s"] - x["gyro_bias_rad_s"]
    f = np.asarray(x["acc_last_m_s2"], dtype=float)
    m = np.asarray(x["mag_last_ut"], dtype=float)
    fc = centripetal_levelling_force(f, rate, float(np.linalg.norm(x["vel_ned_m_s"])))
    if (may_level_again and fc is not None and yaw_from_mag and np.all(np.isfinite(m))
            and _angle_rad(f, fc) > p.init_sigma_tilt_rad):
        level_again(x, P, hist, p, fc, m, declination_rad)
        return True
    widen_for_lean(P, first_fix_lean(x["q"], rate, x["vel_ned_m_s"], f))
    return False


def _angle_rad(u, v) -> float:
    return math.atan2(float(np.linalg.norm(np.cross(u, v))), float(np.dot(u, v)))


def learned_to_keep(x: np.void, restart: bool) -> LearnedErrors:
    """What the state x holds that a restart after a gap keeps (copies); at the first start, nothing."""
    if not restart:
        return LearnedErrors(np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(6), None)
    return LearnedErrors(x["gyro_bias_rad_s"].copy(), x["accel_bias_m_s2"].copy(), x["gyro_scale"].copy(),
                         x["gyro_misalignment_rad"].copy(), x["mag"].copy())


def fresh_state(x_arr: np.ndarray, t_s, q0, g, a, mag_ut) -> None:
    """Clear the state (x_arr, the 1-element record array; but the gyro rotation check's window: the next check's)
    and set the attitude and the last sample; no fix yet, no gate rejections."""
    x = x_arr[0]
    rotation = ("gyro_rotation_rad", "gyro_rotation_s", "gyro_rotation_last_t_s")   # the next check's
    keep_rotation = [x[k].copy() for k in rotation]
    x_arr[:] = 0
    for k, v in zip(rotation, keep_rotation):
        x[k] = v
    x["q"] = q0
    x["t_last_s"] = t_s
    x["gyro_last_rad_s"] = g
    x["acc_last_m_s2"] = a
    x["mag_last_ut"] = mag_ut
    x["acc_ned_lp_m_s2"] = np.asarray(quat_to_dcm(q0), dtype=float) @ a
    x["gnss_fused_t_s"] = -math.inf
    x["last_fix_t_s"] = -math.inf
    x["vel_gate"]["rejected_since_s"] = math.nan
    x["pos_gate"]["rejected_since_s"] = math.nan
    x["vel_gate"]["nis"] = math.nan
    x["pos_gate"]["nis"] = math.nan


def start_sensor_errors(x: np.void, kept: LearnedErrors) -> None:
    """The sensor errors the filter starts from; the GNSS yaw bank's gyro bias is the filter's until the bank's own
    yaw confirms one."""
    x["gyro_bias_rad_s"] = kept.gyro_bias_rad_s
    x["bank_gyro_bias_rad_s"] = kept.gyro_bias_rad_s
    x["accel_bias_m_s2"] = kept.accel_bias_m_s2
    x["gyro_scale"] = kept.gyro_scale
    x["gyro_misalignment_rad"] = kept.gyro_misalignment_rad


def first_history_row(x: np.void, hist: np.ndarray, t_s, q0, g, gyro_bias) -> None:
    """The history's first row: a fix valid at this very sample can be fused."""
    x["hist_newest"] = 0
    x["hist_count"] = 1
    hist[0] = 0
    row = hist[0]
    row["t_s"] = t_s
    row["q"] = q0
    row["rate_rad_s"] = np.asarray(g, dtype=float) - gyro_bias


def start_mag_reference(x: np.void, kept: LearnedErrors, min_undisturbed_s: float) -> None:
    """The magnetometer check's reference field: kept over a restart, else learned anew; counted undisturbed from
    the start (the Wahba heading is already the best)."""
    ms = x["mag"]
    if kept.mag_check is not None:
        ms["ref_norm_ut"] = ms["cand_norm_ut"] = kept.mag_check["ref_norm_ut"]
        ms["ref_dip_rad"] = ms["cand_dip_rad"] = kept.mag_check["ref_dip_rad"]
    ms["undisturbed_t_s"] = min_undisturbed_s


def initial_covariance(P: np.ndarray, p: StartSigmas, use_mag: bool, lean: StartLean | None = None,
                       axis_sigma_rad: float = 0.0) -> None:
    """The start-up uncertainty, uncorrelated: tilt from levelling (at least the `lean` its specific force
    allows), yaw from the magnetometer and its calibration (π, unknown, without it), velocity and position
    unknown until the first fix, the sensor errors their prior σ; the magnetometer's error states zero (the filter
    restarts them from their priors). A lean beyond levelling's own σ also tips the plane the field's heading is
    taken in: the heading is then off by about tan(dip)·lean (the kernel's magnetometer heading row, whose tilt
    part is tan(dip) along the horizontal field), up to π. Levelled on a turn's rotation axis the tilt 1σ is at
    least `axis_sigma_rad` (`axis_levelling_sigma_rad`)."""
    P[:] = 0.0
    lean_rad = 0.0 if lean is None else lean.lean_rad
    for i in (core.E_TILT_N, core.E_TILT_E):
        P[i, i] = max(p.init_sigma_tilt_rad, lean_rad, axis_sigma_rad) ** 2
    yaw_sigma = max(p.init_sigma_yaw_rad, p.calibration_sigma_rad) if use_mag else math.pi
    if use_mag and lean is not None and lean_rad > p.init_sigma_tilt_rad:
        through_dip = abs(math.tan(lean.dip_rad)) * lean_rad if math.isfinite(lean.dip_rad) else math.pi
        yaw_sigma = max(yaw_sigma, min(math.pi, through_dip))
    P[core.E_YAW, core.E_YAW] = yaw_sigma ** 2
    for i in range(3):
        P[core.E_V + i, core.E_V + i] = core.NAV_UNKNOWN_VAR_V
        P[core.E_P + i, core.E_P + i] = core.NAV_UNKNOWN_VAR_P
        P[core.E_BG + i, core.E_BG + i] = p.init_gyro_bias_sigma_rad_s ** 2
        P[core.E_BA + i, core.E_BA + i] = p.init_accel_bias_sigma_m_s2 ** 2
        P[core.E_SG + i, core.E_SG + i] = p.init_gyro_scale_sigma ** 2
    for i in range(6):
        P[core.E_MG + i, core.E_MG + i] = p.init_gyro_misalignment_sigma_rad ** 2
    for i in range(core.N_ACC_Z_LEAN):   # the accelerometer z axis's lean m_zx, m_zy: 0 leaves them at zero
        P[core.E_AZ_LEAN + i, core.E_AZ_LEAN + i] = p.accel_axes_tilt_sigma_rad ** 2


__all__ = ["LearnedErrors", "StartLean", "StartSigmas", "axis_levelling_sigma_rad", "carry_over_fix_delay", "couple_yaw_to_tilt", "centripetal_levelling_force", "first_history_row", "fresh_state", "initial_covariance",
           "first_fix_in_turn", "first_fix_lean", "initial_true_attitude", "learned_to_keep", "level_again", "levelling_force", "levelling_lean",
           "start_mag_reference", "start_sensor_errors", "tilt_through_dip_row", "widen_for_lean"]
