"""The latest estimate of a stepping estimator: what `step(sample)` returns (estimator.base.SteppingEstimator).

At 819.2 SPS the daemon's publishers want an estimate 30–50 times a second, not after every sample; building the
immutable AttitudeEstimate (a fresh output buffer, NavState, the heading state) costs several times the filter
step's own Python around the compiled kernel. So `step` returns a view, one per estimator, reused: `t_s`,
`valid` and `flags` are read per sample, `snapshot()` is the AttitudeEstimate `update` returns for the sample
stepped last, and every other field of the AttitudeEstimate (`roll_rad`, `nav`, …) is a member of the view
(`EstimateView` declares each one, reading the snapshot; a view that reads a field in place declares its own).

`EstimateView` is that one concept; an estimator gives it in one of two ways, and the difference is what a
change between a step and a read does:

- **read in place** (`mekf.MekfView`): the attributes read the estimator's output buffer when accessed (arrays
  are views of it: copy what you keep) and `snapshot()` copies it. For an estimator whose published estimate
  is its filter's output as it stands, nothing outside `step` changes that buffer; a setting changed after a
  step shows at the next read (mekf: the declination, in `heading_true_rad`).
- **built on demand** (`BuiltEstimateView`, ins): the estimator's builder makes the AttitudeEstimate at the
  first request after a step and the view keeps it; other attributes read that snapshot. Everything that moves
  with each sample (the filter, the published-heading slew) is done in `step`, so what a snapshot holds does
  not depend on how often snapshots are taken. An estimator whose other methods change what the builder reads
  (a GNSS fix fused, a declination or calibration set, a reset) calls `freeze()` before the change, so the
  estimate of the sample already stepped is the one that sample had."""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from ahrsd.core.estimate import AttitudeEstimate, EstimateFlags, HeadingIntegrity, HeadingState, NavState

from .filter_output import estimate_flags

_INITIALISING = EstimateFlags.INITIALISING


class EstimateView:
    """The latest estimate of a stepping estimator (module docstring). A subclass gives `t_s`, `valid`,
    `flags` and `snapshot()`, and may read any other field in place (overriding its member here); the rest
    read the snapshot."""

    __slots__ = ()

    t_s: float                  # the time of the sample stepped last (NaN: none yet)
    valid: bool                 # the filter is initialised (else the snapshot is the uninitialised estimate)
    flags: EstimateFlags

    def snapshot(self) -> AttitudeEstimate:
        """The immutable AttitudeEstimate of the sample stepped last, the one `update` returns."""
        raise NotImplementedError

    def freeze(self) -> None:
        """The estimator is about to change something a read after the step would see (a view read in place
        shows such a change: nothing to do)."""

    # The other fields of the AttitudeEstimate read the snapshot; a view that reads one in place (mekf.MekfView)
    # declares its own. Named one by one, not forwarded wholesale, so what a view has is read here.
    @property
    def q_wxyz(self) -> np.ndarray:
        return self.snapshot().q_wxyz

    @property
    def roll_rad(self) -> float:
        return self.snapshot().roll_rad

    @property
    def pitch_rad(self) -> float:
        return self.snapshot().pitch_rad

    @property
    def yaw_rad(self) -> float:
        return self.snapshot().yaw_rad

    @property
    def heading_mag_rad(self) -> float:
        return self.snapshot().heading_mag_rad

    @property
    def heading_true_rad(self) -> float:
        return self.snapshot().heading_true_rad

    @property
    def rate_body_rad_s(self) -> np.ndarray:
        return self.snapshot().rate_body_rad_s

    @property
    def gyro_bias_rad_s(self) -> np.ndarray:
        return self.snapshot().gyro_bias_rad_s

    @property
    def sigma_rpy_rad(self) -> np.ndarray:
        return self.snapshot().sigma_rpy_rad

    @property
    def nav(self) -> NavState | None:
        return self.snapshot().nav

    @property
    def heading_state(self) -> HeadingState:
        return self.snapshot().heading_state

    @property
    def integrity(self) -> HeadingIntegrity | None:
        return self.snapshot().integrity


class BuiltEstimateView(EstimateView):
    """The view built on demand: `build(t_s, flag_bits, initialised) -> AttitudeEstimate` is the estimator's
    builder; the estimator calls `set` after each step and `freeze` before a change its builder reads.
    `snapshots_built` counts the builds (what the daemon's on-demand rule saves is counted on it)."""

    __slots__ = ("_build", "t_s", "bits", "valid", "_estimate", "snapshots_built")

    def __init__(self, build: Callable[[float, int, bool], AttitudeEstimate]):
        self._build = build
        self.t_s = math.nan
        self.bits = 0
        self.valid = False
        self._estimate: AttitudeEstimate | None = None
        self.snapshots_built = 0

    def set(self, t_s: float, flag_bits: int, valid: bool) -> None:
        """A sample was stepped: its time, its estimate's flag bits, whether the filter is initialised."""
        self.t_s = t_s
        self.bits = flag_bits
        self.valid = valid
        self._estimate = None

    @property
    def flags(self) -> EstimateFlags:
        f = estimate_flags(self.bits)
        return f if self.valid else _INITIALISING | f

    def snapshot(self) -> AttitudeEstimate:
        """The AttitudeEstimate of the sample stepped last (built at the first call after the step)."""
        e = self._estimate
        if e is None:
            e = self._estimate = self._build(self.t_s, self.bits, self.valid)
            self.snapshots_built += 1
        return e

    def freeze(self) -> None:
        """Build the snapshot now if a sample was stepped and it is not built yet: the estimator is about to
        change something the builder reads."""
        if self._estimate is None and self.t_s == self.t_s:
            self.snapshot()
