"""The estimator interface shared by every attitude estimator (CONTRIBUTING.md)."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from ahrsd.core.estimate import AttitudeEstimate
from ahrsd.core.gnss import GnssFix
from ahrsd.core.sample import ImuSample

from .estimate_view import EstimateView


class Estimator(Protocol):
    name: str

    def update(self, sample: ImuSample) -> AttitudeEstimate: ...

    def reset(self) -> None: ...

    def set_declination(self, declination_rad: float) -> None: ...

    def relearn_field_reference(self, heading_change_rad: float = float("nan")) -> None:
        """The magnetometer calibration changed: re-learn whatever reference of the field the estimator
        keeps (magnitude, dip) from the next samples, keeping attitude and gyro bias (no heading step).
        heading_change_rad: how far the new calibration moves the heading on the current sample (NaN: not
        known); a filter with a heading variance raises it to cover that much (mag_heading.widen_heading_variance)."""


@runtime_checkable
class SteppingEstimator(Estimator, Protocol):
    """An estimator with a cheap hot path (mekf, ins): `step(sample)` updates like `update` but returns a reused,
    view of the estimate (estimate_view.EstimateView: the AttitudeEstimate's fields, valid until the next step)
    with `snapshot() -> AttitudeEstimate`, so a caller that publishes at a lower rate builds the immutable result
    only then. The daemon's pipeline uses it where an estimator has it (daemon/pipeline.py)."""

    def step(self, sample: ImuSample) -> EstimateView: ...


@runtime_checkable
class BlockSteppingEstimator(SteppingEstimator, Protocol):
    """A stepping estimator that also steps a run of a block's samples in one call (ins: `Ins.step_block(t_s,
    rows, sample_flags)` → the stepped samples' flags and its view, or None to step them one by one); the daemon's
    pipeline uses it where the reader's listeners allow (daemon/pipeline.py `process_block`)."""

    def step_block(self, t_s, rows, sample_flags) -> tuple[list, EstimateView] | None: ...


@runtime_checkable
class GnssAidedEstimator(Protocol):
    """An estimator that takes GNSS fixes (ins): `update_gnss(fix)` returns the core.R_* bits of what became of
    the fix and never raises on bad input; `gnss_counters` counts what became of the fixes offered (offered,
    fused_velocity, fused_position, rejected_velocity, rejected_position, …, `as_dict()`: estimator/ins.py
    GnssCounters); `lever_arm_m` is where it was told the antenna is (x, y, z from the IMU, body FRD, m), which a
    report of rejected velocities names; `lever_arm_fit()` says whether its velocity innovations put the antenna
    elsewhere (estimator/lever_arm_fit.py LeverArmFitResult, None before it can say; read its latches `arm_wrong` and
    `heading_bent`, not the momentary `explains`); `lever_arm_adopted_m()` the correction to the told arm it adopted
    and fuses with (None: none), which costs no fit. The daemon's GNSS task offers
    it every accepted fix and watches its innovation gate; replay merges a GNSS recording's fixes with the samples."""

    name: str
    gnss_counters: object
    lever_arm_m: tuple[float, float, float]

    def update_gnss(self, fix: GnssFix) -> int: ...

    def lever_arm_fit(self): ...

    def lever_arm_adopted_m(self): ...


@runtime_checkable
class MagCalibrationAwareEstimator(Protocol):
    """An estimator told the heading error its magnetometer calibration predicts (1σ rad, NaN: no calibration or
    its quality unknown; calibration/heading_trust.py), at start and after every calibration change. Without GNSS
    its published yaw 1σ includes it (estimator/calibration_heading.py); ins also weighs its checks with it."""

    def set_mag_calibration_sigma(self, sigma_rad: float) -> None: ...


@runtime_checkable
class MagFrameTiltAwareEstimator(Protocol):
    """An estimator told the tilt of its magnetometer calibration's frame against the body (1σ per axis, rad; 0: none
    stated, the frame is the body's; calibration/heading_trust.calibration_frame_tilt_sigma_rad), at start and after
    every calibration change, after `set_mag_calibration_sigma` (ins: estimator/mag_frame_tilt.py), with the share of
    the calibration's heading error that tilt makes (rad; heading_trust.calibration_frame_tilt_heading_sigma_rad)."""

    def set_mag_calibration_frame_tilt_sigma(self, sigma_rad: float, heading_sigma_rad: float = 0.0) -> None: ...


@runtime_checkable
class AccelCalibrationAwareEstimator(Protocol):
    """An estimator whose published tilt σ carries the accelerometer bias its input still has (1σ per axis, m/s²;
    None: no accelerometer calibration, the chip's figure the estimator was built with; calibration/accel_trust.py),
    told at start and after every calibration change (mekf)."""

    def set_accel_bias_sigma(self, sigma_m_s2: float | None) -> None: ...


@runtime_checkable
class FieldCircleCheckedEstimator(Protocol):
    """An estimator that checks its magnetometer calibration without GNSS by the circle the levelled field sweeps in
    turns (mekf: estimator/field_circle.py) and adds the heading error a wrong one implies to its published σ.
    `field_circle()`: the latest FieldCircleResult while the check governs the σ, else None. (ins runs the check
    before its first fix for its σ only: Ins.field_circle_check.)"""

    def field_circle(self): ...


@runtime_checkable
class HeadingCheckedEstimator(Protocol):
    """An estimator that checks its heading against GNSS (ins): it counts the resets of its yaw to the GNSS
    yaw, takes the heading error a magnetometer calibration predicts (1σ, rad) into its checks, and reports
    what the checks did (`heading_report()`: mag_rejections, max_disagreement_deg, yaw_resets)."""

    yaw_resets: int
    gnss_yaw_alignments: int    # those of the resets that were the planned first alignment (no trusted calibration)

    def set_mag_calibration_sigma(self, sigma_rad: float) -> None: ...

    def heading_report(self): ...


LEARNED_WITH_GNSS = "GNSS-aided ins"   # ins: estimator/heading_monitor.py IronLearner
LEARNED_IN_TURNS = "turns, no GNSS"    # mekf: estimator/field_circle_correction.py
# 1σ per axis, µT, of the field error a learned iron does not explain (WMM and local anomalies): ins's default
# (InsParams.iron_unmodelled_ut), and mekf's figure for the hard iron it learns in turns
DEFAULT_UNMODELLED_IRON_UT = 1.0


@runtime_checkable
class IronLearningEstimator(Protocol):
    """An estimator that learns the vehicle's iron on top of the calibration in operation (ins: estimator/heading_
    monitor.py IronLearner; mekf: the hard iron in turns, estimator/field_circle_correction.py), body frame. The
    daemon persists, shows and folds it (daemon/learned_iron.py); `learned_iron_source` says what learned it."""

    learned_iron_source: str
    # the field error (1σ per axis, µT) the learned iron does not explain: over the horizontal field, the floor of
    # the heading error of a calibration with the learned iron folded in, when that calibration states none
    unmodelled_iron_ut: float

    def learned_iron(self) -> tuple[np.ndarray, np.ndarray]:
        """The hard iron (µT) and its 3×3 covariance (µT²)."""

    def learned_soft_iron(self) -> tuple[np.ndarray, np.ndarray]:
        """The soft iron I + D and the 9×9 covariance of D's elements, row by row."""

    def learned_iron_heading_sigma_rad(self) -> float:
        """The largest heading 1σ the learned iron leaves on a level vehicle, rad; NaN while unknown."""

    def set_learned_iron(self, offset_ut, cov_ut2, soft_iron=None, soft_cov=None) -> None:
        """Start from an iron persisted earlier; ValueError when it is not finite or not positive definite."""

    def reset_learned_iron(self) -> None: ...
