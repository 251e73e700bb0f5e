"""The learning window's yaw error in a learned iron: how much of the filter's yaw error over the window the
learned iron has taken in, carried beside the learner's covariance.

`IronLearner` (heading_monitor.py) learns the iron against the filter's attitude and counts that attitude's
uncertainty as measurement noise refreshed every `iron_tau_s` (5 s), as if the attitude error were new every
5 s. The yaw error is not: on a boat or a car between GNSS-observable manoeuvres it is the same for tens of
seconds (the gyro's bias drift over the window, what the GNSS velocity has not yet corrected), so over a
learning window of a minute or more it is one error, common to every update, which the learner's covariance
states averaged down by the number of updates. A common yaw error δψ rotates the Earth field about the vertical
in every measurement, and the learned iron fits that rotation as iron: fully, as an offset of the learned
magnetometer's heading at every heading, where the soft iron's prior lets D take a rotation (the uncalibrated
magnetometer, D ~ 0.1); hardly at all where it pins D (a calibrated magnetometer whose iron stepped: a hard iron
cannot turn the field at every heading, only over the part of a turn the window saw).

This is a consider (Schmidt) sensitivity of the learner to that error (Maybeck, Stochastic Models, Estimation
and Control vol. 1, §6.8; Bierman, Factorization Methods, ch. VII): the learner's update is left as it is, and
the share s (12, in the learner's units) of its error that the window's yaw error makes is propagated with the
learner's own gain, the yaw error taken at the filter's yaw 1σ at each update and fully correlated over the
window (its correlation time longer than the window):

    s ← (I − K H) s + K j_ψ σ_ψ

with j_ψ = ∂m/∂δψ (the learner's attitude Jacobian's column about the vertical, j = (I + D) C_bnᵀ [B×]). The
learned iron's error then has covariance cov + s sᵀ; s sᵀ is what `Ins` adds to the learner's covariance where
the learned magnetometer's heading error is projected on the harmonic states.
"""

from __future__ import annotations

import math

import numpy as np

from .heading_monitor import N_IRON

_DOWN = 2
"""The attitude error's component about the vertical (the yaw error; ins_core E_YAW is E_TH + 2)."""


class WindowYawShare:
    """The learned iron's error that the learning window's yaw error made, 1σ (N_IRON, µT and dimensionless as
    IronLearner's state); zero before any learning and after a reset, or for an iron restored from disk (what
    its window's yaw was is not persisted)."""

    def __init__(self) -> None:
        self.share = np.zeros(N_IRON)

    def reset(self) -> None:
        self.share = np.zeros(N_IRON)

    def step(self, gain: np.ndarray, jacobian: np.ndarray, attitude_jacobian: np.ndarray,
             yaw_sigma_rad: float) -> None:
        """After one IronLearner update with gain K (N_IRON×3), measurement Jacobian H (3×N_IRON) and attitude
        Jacobian j (3×3), the filter's yaw 1σ at that update (rad)."""
        sigma = float(yaw_sigma_rad) if math.isfinite(yaw_sigma_rad) and yaw_sigma_rad > 0.0 else 0.0
        k = np.asarray(gain, dtype=float)
        kept = self.share - k @ (np.asarray(jacobian, dtype=float) @ self.share)
        self.share = kept + k @ np.asarray(attitude_jacobian, dtype=float)[:, _DOWN] * sigma

    def cov(self) -> np.ndarray:
        """s sᵀ: the covariance this share adds to the learner's (N_IRON×N_IRON)."""
        return np.outer(self.share, self.share)
