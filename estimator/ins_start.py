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

from . import ins_core as core
from .initial_attitude import initial_attitude
from .rotations import quat_to_dcm


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


def initial_covariance(P: np.ndarray, p: StartSigmas, use_mag: bool) -> None:
    """The start-up uncertainty, uncorrelated: tilt from levelling, yaw from the magnetometer and its
    calibration (π, unknown, without it), velocity and position unknown until the first fix, the sensor
    errors their prior σ; the magnetometer's error states zero (the filter restarts them from their priors)."""
    P[:] = 0.0
    for i in (core.E_TILT_N, core.E_TILT_E):
        P[i, i] = p.init_sigma_tilt_rad ** 2
    P[core.E_YAW, core.E_YAW] = (max(p.init_sigma_yaw_rad, p.calibration_sigma_rad) if use_mag else math.pi) ** 2
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


__all__ = ["LearnedErrors", "StartSigmas", "first_history_row", "fresh_state", "initial_covariance",
           "initial_true_attitude", "learned_to_keep", "start_mag_reference", "start_sensor_errors"]
