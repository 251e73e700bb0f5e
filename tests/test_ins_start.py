"""How ins starts its kernel's state (estimator/ins_start.py), without a filter: the start-up covariance from the
stated 1σ's, what a restart after a gap keeps, the gyro rotation window kept over the clearing, the history's first
row. The expected values are the 1σ's squared and the values written in, by hand."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from ahrsd.estimator import ins_core as core
from ahrsd.estimator.ins_start import (first_history_row, fresh_state, initial_covariance, learned_to_keep,
                                       start_mag_reference, start_sensor_errors)

SIGMAS = SimpleNamespace(init_sigma_tilt_rad=0.05, init_sigma_yaw_rad=0.2, calibration_sigma_rad=0.3,
                         init_gyro_bias_sigma_rad_s=0.01, init_accel_bias_sigma_m_s2=0.2, init_gyro_scale_sigma=0.02,
                         init_gyro_misalignment_sigma_rad=0.003, accel_axes_tilt_sigma_rad=0.004)


@pytest.mark.parametrize("use_mag, yaw_sigma", [(True, 0.3), (False, math.pi)])
def test_the_start_up_covariance_is_the_stated_sigmas_uncorrelated(use_mag, yaw_sigma):
    P = np.full((core.N_ERR, core.N_ERR), 7.0)
    initial_covariance(P, SIGMAS, use_mag)
    d = np.diag(P)
    assert d[core.E_TILT_N] == d[core.E_TILT_E] == 0.05 ** 2
    assert d[core.E_YAW] == yaw_sigma ** 2        # the calibration's 0.3 above the 0.2 start-up figure; π without
    assert np.all(d[core.E_V:core.E_V + 3] == core.NAV_UNKNOWN_VAR_V)
    assert np.all(d[core.E_BG:core.E_BG + 3] == 0.01 ** 2)
    assert np.all(d[core.E_BA:core.E_BA + 3] == 0.2 ** 2)
    assert np.all(d[core.E_MG:core.E_MG + 6] == 0.003 ** 2)
    assert np.all(d[core.E_AZ_LEAN:core.E_AZ_LEAN + core.N_ACC_Z_LEAN] == 0.004 ** 2)
    assert np.count_nonzero(P - np.diag(d)) == 0


def test_a_restart_keeps_the_learned_errors_and_the_field_reference_a_start_does_not():
    x_arr = np.zeros(1, core.INS_STATE_DTYPE)
    x = x_arr[0]
    x["gyro_bias_rad_s"] = (1e-3, 2e-3, 3e-3)
    x["accel_bias_m_s2"] = (0.1, 0.2, 0.3)
    x["gyro_rotation_s"] = 0.4
    x["mag"]["ref_norm_ut"] = 48.0
    kept = learned_to_keep(x, restart=True)
    first = learned_to_keep(x, restart=False)
    assert first.mag_check is None and not np.any(first.gyro_bias_rad_s)
    q0 = np.array([1.0, 0.0, 0.0, 0.0])
    fresh_state(x_arr, 5.0, q0, np.zeros(3), np.array([0.0, 0.0, -9.8]), np.full(3, np.nan))
    assert x["gyro_rotation_s"] == 0.4                       # the rotation check's window goes on
    assert not np.any(x["gyro_bias_rad_s"]) and x["t_last_s"] == 5.0
    assert math.isnan(x["vel_gate"]["nis"]) and x["gnss_fused_t_s"] == -math.inf
    start_sensor_errors(x, kept)
    start_mag_reference(x, kept, 2.5)
    assert np.array_equal(x["gyro_bias_rad_s"], [1e-3, 2e-3, 3e-3])
    assert np.array_equal(x["bank_gyro_bias_rad_s"], [1e-3, 2e-3, 3e-3])
    assert np.array_equal(x["accel_bias_m_s2"], [0.1, 0.2, 0.3])
    assert x["mag"]["ref_norm_ut"] == x["mag"]["cand_norm_ut"] == 48.0
    assert x["mag"]["undisturbed_t_s"] == 2.5
    hist = np.ones(core.H_LEN, core.INS_HISTORY_DTYPE)
    first_history_row(x, hist, 5.0, q0, np.array([0.1, 0.0, 0.0]), kept.gyro_bias_rad_s)
    assert (x["hist_newest"], x["hist_count"], hist[0]["t_s"]) == (0, 1, 5.0)
    assert np.allclose(hist[0]["rate_rad_s"], [0.099, -2e-3, -3e-3], rtol=0, atol=1e-15)
    assert not np.any(hist[0]["vel_ned_m_s"])                # the rest of the row cleared
