"""The magnetometer's error states restarted from their priors (ins.Ins at start-up, a new calibration, a yaw reset,
the iron learning ended): the five heading harmonics (mag_harmonics.py) and the calibration frame's tilt about body
x and y (mag_frame_tilt.py).

The functions keep no state and read nothing of the filter: Ins hands them the kernel's state record and
covariance, which they write (the states to zero, their rows and columns of P to their prior), and the figures the
priors are made of. Which error the harmonics carry (the calibration's, the learned iron's or none) is
mag_error_states.py's decision.
"""

from __future__ import annotations

import math

import numpy as np

from . import ins_core as core
from .mag_frame_tilt import N_MAG_FRAME_TILT, accel_bias_share
from .mag_harmonics import prior_from_heading_rows, prior_variances_rad2

IRON_HARMONIC_YAWS_RAD = np.linspace(0.0, 2.0 * math.pi, 16, endpoint=False)
"""The headings a learned iron's heading error is fitted on (`iron_harmonics_prior`): 16, as
IronLearner.level_heading_variance's."""


def restart_harmonics(x, P: np.ndarray, prior_rad2: np.ndarray | None) -> None:
    """The harmonic states back to zero (the state record x, written) with the 5×5 prior (rad²) in P, uncorrelated
    with every other state; None (the harmonics off): zero with zero variance, they never move."""
    x["mag_heading_error_rad"] = 0.0
    block = slice(core.E_MH, core.E_MF)
    P[block, :] = 0.0
    P[:, block] = 0.0
    if prior_rad2 is not None:
        P[block, block] = prior_rad2


def calibration_harmonics_prior(calibration_sigma_rad: float, offset_share: float,
                                frame_tilt_heading_sigma_rad: float) -> np.ndarray:
    """The harmonic states' prior for a calibration's heading error (5×5, rad², uncorrelated): its stated 1σ split
    between the offset and the harmonics (mag_harmonics.prior_variances_rad2), less the share the frame-tilt states
    carry (`frame_tilt_heading_sigma_rad`, 0: none), which would otherwise count twice."""
    return np.diag(prior_variances_rad2(calibration_sigma_rad, offset_share, frame_tilt_heading_sigma_rad))


def iron_harmonics_prior(heading_rows: np.ndarray, magnetic_yaws_rad: np.ndarray, iron_cov: np.ndarray,
                         floor_var_rad2: float, residual_share: float, offset_share: float) -> np.ndarray:
    """The harmonic states' prior for a learned iron (5×5, rad²): its covariance (`iron_cov`, the learner's plus the
    window's yaw share, iron_in_use.IronInUse.harmonic_cov) projected through the heading rows of a level vehicle at
    the WMM field at the magnetic headings given (`prior_from_heading_rows`), plus the part of the floor
    (`floor_var_rad2`, what no learned iron explains) not fused as noise (1 − `residual_share`), split as a
    calibration's."""
    prior = prior_from_heading_rows(heading_rows, magnetic_yaws_rad, iron_cov)
    floor_sigma = math.sqrt(max(0.0, 1.0 - residual_share) * floor_var_rad2)
    return prior + np.diag(prior_variances_rad2(floor_sigma, offset_share))


def frame_tilt_heading_sigma_rad(harmonics_on: bool, frame_tilt_sigma_rad: float, heading_share_rad: float) -> float:
    """The share of the calibration's heading error the frame-tilt states carry (rad): its stated share while they
    are on with the calibration's harmonics (harmonics on and a stated frame tilt); else 0."""
    tilt = float(frame_tilt_sigma_rad)
    share = float(heading_share_rad)
    on = harmonics_on and math.isfinite(tilt) and tilt > 0.0
    return share if on and math.isfinite(share) and share > 0.0 else 0.0


def restart_frame_tilt(x, P: np.ndarray, on: bool, sigma_rad: float, shares_accel_bias: bool) -> None:
    """The frame-tilt states back to zero (the state record x, written) with the calibration's prior in P (its
    stated tilt σ² per axis); off, zero with zero variance: they never move. With `shares_accel_bias` the prior is
    the frame-tilt prior of mag_frame_tilt.py: the tilt is partly the filter's own accelerometer-bias error, so it is
    correlated with that bias and with what the bias is correlated with."""
    x["mag_frame_tilt_rad"] = 0.0
    block = slice(core.E_MF, core.E_MF + N_MAG_FRAME_TILT)
    P[block, :] = 0.0
    P[:, block] = 0.0
    if on:
        sigma = float(sigma_rad)
        gain = accel_bias_share(sigma, np.diag(P)[core.E_BA:core.E_BA + 3]) if shares_accel_bias else np.zeros((2, 3))
        bias = slice(core.E_BA, core.E_BA + 3)
        cross = gain @ P[bias, :]        # ε = G δb_a + w: Cov(ε, δx) = G Cov(δb_a, δx)
        P[block, :] = cross
        P[:, block] = cross.T
        shared = gain @ P[bias, bias] @ gain.T
        P[block, block] = shared + np.diag(sigma ** 2 - np.diag(shared))    # w: the rest of σ² per axis
