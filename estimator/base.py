"""The estimator interface shared by every attitude estimator (CONTRIBUTING.md)."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from ahrsd.core.estimate import AttitudeEstimate
from ahrsd.core.sample import ImuSample


class Estimator(Protocol):
    name: str

    def update(self, sample: ImuSample) -> AttitudeEstimate: ...

    def reset(self) -> None: ...

    def set_declination(self, declination_rad: float) -> None: ...

    def relearn_field_reference(self) -> None:
        """The magnetometer calibration changed: re-learn whatever reference of the field the estimator
        keeps (magnitude, dip) from the next samples, keeping attitude and gyro bias (no heading step)."""


@runtime_checkable
class SteppingEstimator(Estimator, Protocol):
    """An estimator with a cheap hot path (mekf): `step(sample)` updates like `update` but returns a reused,
    in-place view of the estimate (the AttitudeEstimate's fields, valid until the next step) with
    `snapshot() -> AttitudeEstimate`, so a caller that publishes at a lower rate builds the immutable result
    only then. The daemon's pipeline uses it where an estimator has it (daemon/pipeline.py)."""

    def step(self, sample: ImuSample): ...


@runtime_checkable
class HeadingCheckedEstimator(Protocol):
    """An estimator that checks its heading against GNSS (ins): it counts the resets of its yaw to the GNSS
    yaw and takes the heading error a magnetometer calibration predicts (1σ, rad) into its checks."""

    yaw_resets: int

    def set_mag_calibration_sigma(self, sigma_rad: float) -> None: ...
