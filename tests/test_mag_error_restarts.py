"""The magnetometer's error states restarted from their priors, the functions alone (estimator/mag_error_restarts.py),
on a covariance built here without a filter: each restart zeroes its states, clears their rows and columns and
leaves every other entry alone; the calibration's harmonic prior sums to its σ² less the frame tilt's share at any
heading; a learned iron's prior is the covariance of the harmonic coefficients of a heading error that is itself a
harmonic series; the frame tilt's prior is σ² per axis, correlated with the accelerometer bias as ε = G δb_a + w with
G written out here from mag_frame_tilt.py's rule. The expected values are computed in the test, not read from the
functions."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ahrsd.estimator import ins_core as core
from ahrsd.estimator.mag_error_restarts import (IRON_HARMONIC_YAWS_RAD, calibration_harmonics_prior,
                                                frame_tilt_heading_sigma_rad, iron_harmonics_prior,
                                                restart_frame_tilt, restart_harmonics)
from ahrsd.estimator.heading_monitor import N_IRON

DEG = math.pi / 180.0
G = 9.80665
HARMONICS = slice(core.E_MH, core.E_MF)
TILT = slice(core.E_MF, core.E_MF + 2)
BIAS = slice(core.E_BA, core.E_BA + 3)


def _covariance(seed: int = 3) -> np.ndarray:
    a = np.random.default_rng(seed).normal(size=(core.N_ERR, core.N_ERR))
    return a @ a.T * 1e-3 + np.eye(core.N_ERR) * 1e-4


def _state():
    x = np.zeros(1, core.INS_STATE_DTYPE)[0]
    x["mag_heading_error_rad"] = 0.01
    x["mag_frame_tilt_rad"] = 0.02
    return x


def _others_unchanged(before: np.ndarray, after: np.ndarray, block: slice) -> bool:
    keep = np.ones(core.N_ERR, dtype=bool)
    keep[block] = False
    return np.array_equal(before[np.ix_(keep, keep)], after[np.ix_(keep, keep)])


def _heading_sum(prior: np.ndarray, psi: float) -> float:
    h = np.array([1.0, math.cos(psi), math.sin(psi), math.cos(2 * psi), math.sin(2 * psi)])
    return float(h @ prior @ h)


@pytest.mark.parametrize("on", [True, False])
def test_the_harmonics_restart_from_their_prior_uncorrelated_or_off(on):
    P0, x = _covariance(), _state()
    P = P0.copy()
    a = np.random.default_rng(7).normal(size=(5, 5))
    prior = a @ a.T * 1e-4         # a learned iron's prior is correlated
    restart_harmonics(x, P, prior if on else None)
    assert not np.any(x["mag_heading_error_rad"]) and np.any(x["mag_frame_tilt_rad"])
    assert np.array_equal(P[HARMONICS, HARMONICS], prior if on else np.zeros((5, 5)))
    rest = np.ones(core.N_ERR, dtype=bool)
    rest[HARMONICS] = False
    assert not np.any(P[HARMONICS][:, rest]) and not np.any(P[rest][:, HARMONICS])
    assert _others_unchanged(P0, P, HARMONICS)


@pytest.mark.parametrize("share_deg", [0.0, 0.3, 0.9])
def test_the_calibrations_prior_sums_to_its_variance_less_the_frame_tilts_share_at_any_heading(share_deg):
    sigma = 1.0 * DEG
    prior = calibration_harmonics_prior(sigma, 0.3, share_deg * DEG)
    assert np.array_equal(prior, np.diag(np.diag(prior)))
    for psi in np.linspace(0.0, 2 * math.pi, 7):
        assert _heading_sum(prior, psi) == pytest.approx(sigma ** 2 - (share_deg * DEG) ** 2, rel=1e-12)
    assert prior[0, 0] == pytest.approx(0.3 * sigma ** 2 if share_deg < 0.9 else prior[0, 0], rel=1e-12)


def test_a_learned_irons_prior_is_the_covariance_of_a_harmonic_heading_errors_coefficients():
    psi = IRON_HARMONIC_YAWS_RAD - 0.2          # the magnetic headings
    rows = np.zeros((len(psi), N_IRON))
    rows[:, :5] = np.stack([np.ones_like(psi), np.cos(psi), np.sin(psi), np.cos(2 * psi), np.sin(2 * psi)], axis=1)
    a = np.random.default_rng(5).normal(size=(N_IRON, N_IRON))
    cov = a @ a.T * 1e-5
    prior = iron_harmonics_prior(rows, psi, cov, 0.0, 0.25, 0.4)
    assert np.allclose(prior, cov[:5, :5], rtol=1e-9, atol=1e-15)
    floor = (0.5 * DEG) ** 2
    only_floor = iron_harmonics_prior(rows, psi, np.zeros((N_IRON, N_IRON)), floor, 0.25, 0.4)
    for p in np.linspace(0.0, 2 * math.pi, 5):       # the floor's unfused part, split as a calibration's
        assert _heading_sum(only_floor, p) == pytest.approx(0.75 * floor, rel=1e-12)
    assert only_floor[0, 0] == pytest.approx(0.4 * 0.75 * floor, rel=1e-12)
    assert not np.any(iron_harmonics_prior(rows, psi, np.zeros((N_IRON, N_IRON)), floor, 1.0, 0.4))


def test_the_frame_tilts_heading_share_only_while_it_is_carried():
    share = 0.2 * DEG
    assert frame_tilt_heading_sigma_rad(True, 0.1 * DEG, share) == share
    assert frame_tilt_heading_sigma_rad(False, 0.1 * DEG, share) == 0.0     # the harmonics off
    assert frame_tilt_heading_sigma_rad(True, 0.0, share) == 0.0            # no frame tilt stated
    assert frame_tilt_heading_sigma_rad(True, math.nan, share) == 0.0
    assert frame_tilt_heading_sigma_rad(True, 0.1 * DEG, math.nan) == 0.0
    assert frame_tilt_heading_sigma_rad(True, 0.1 * DEG, -share) == 0.0


def test_the_frame_tilt_restarts_at_its_sigma_uncorrelated_or_off():
    P0, x = _covariance(), _state()
    P = P0.copy()
    restart_frame_tilt(x, P, True, 0.1 * DEG, False)
    assert not np.any(x["mag_frame_tilt_rad"]) and np.any(x["mag_heading_error_rad"])
    assert np.array_equal(P[TILT, TILT], np.eye(2) * (0.1 * DEG) ** 2)
    assert np.count_nonzero(P[TILT, :]) == 2 and _others_unchanged(P0, P, TILT)
    P = P0.copy()
    restart_frame_tilt(x, P, False, 0.1 * DEG, True)
    assert not np.any(P[TILT, :]) and not np.any(P[:, TILT]) and _others_unchanged(P0, P, TILT)


@pytest.mark.parametrize("bias_sigma_m_s2", [0.005, 0.05])
def test_the_frame_tilt_shares_the_accelerometer_bias_error(bias_sigma_m_s2):
    """ε_x = k_y δb_y / g + w_x, ε_y = −k_x δb_x / g + w_y, k = min(1, (g σ)² / var(δb)) per axis."""
    sigma = 0.1 * DEG
    P0 = _covariance()
    for i in range(3):      # the bias's own variance as given; its correlations kept
        scale = bias_sigma_m_s2 / math.sqrt(P0[core.E_BA + i, core.E_BA + i])
        P0[core.E_BA + i, :] *= scale
        P0[:, core.E_BA + i] *= scale
    P, x = P0.copy(), _state()
    restart_frame_tilt(x, P, True, sigma, True)
    var = np.diag(P0)[BIAS]
    k = [min(1.0, (G * sigma) ** 2 / v) for v in var[:2]]
    gain = np.zeros((2, 3))
    gain[0, 1], gain[1, 0] = k[1] / G, -k[0] / G
    rest = np.ones(core.N_ERR, dtype=bool)
    rest[TILT] = False
    assert np.allclose(P[TILT][:, rest], (gain @ P0[BIAS, :])[:, rest], rtol=1e-12, atol=1e-18)
    assert np.array_equal(P[rest][:, TILT], P[TILT][:, rest].T)
    assert np.allclose(np.diag(P[TILT, TILT]), sigma ** 2, rtol=1e-12, atol=0.0)
    assert np.allclose(P[TILT, TILT], P[TILT, TILT].T, rtol=0.0, atol=0.0)
    assert np.all(np.linalg.eigvalsh(P) > -1e-15)          # still a covariance
    assert _others_unchanged(P0, P, TILT)
