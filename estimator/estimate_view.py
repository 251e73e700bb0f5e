"""The latest estimate of an estimator whose AttitudeEstimate is built only when someone asks for it.

At 819.2 SPS the daemon's publishers want an estimate 30–50 times a second, not after every sample; building the
immutable AttitudeEstimate (a fresh output buffer, NavState, the heading state) costs several times the filter
step's own Python around the compiled kernel. An estimator with a `step(sample)` (estimator.base.
SteppingEstimator) returns this view: its `flags` are read per sample, `snapshot()` builds the AttitudeEstimate
of the sample stepped last — the same object `update` returns — once, on first request.

Everything that moves in `step` (the filter, the published-heading slew) is done there for every sample, so
what a snapshot holds does not depend on how often snapshots are taken. An estimator whose other methods change
what a snapshot reads (a GNSS fix fused, a declination or calibration set, a reset) calls `freeze()` before the
change, so the estimate of the sample already stepped is the one that sample had."""

from __future__ import annotations

import math
from typing import Callable

from ahrsd.core.estimate import AttitudeEstimate, EstimateFlags

from .filter_output import estimate_flags

_INITIALISING = EstimateFlags.INITIALISING


class EstimateView:
    """`build(t_s, flag_bits, initialised) -> AttitudeEstimate` is the estimator's builder; `set` after each step.
    Any attribute of the AttitudeEstimate (`roll_rad`, `nav`, …) reads the snapshot."""

    __slots__ = ("_build", "t_s", "bits", "valid", "_estimate")

    def __init__(self, build: Callable[[float, int, bool], AttitudeEstimate]):
        self._build = build
        self.t_s = math.nan
        self.bits = 0
        self.valid = False          # the filter is initialised (else the snapshot is the uninitialised estimate)
        self._estimate: AttitudeEstimate | None = None

    def set(self, t_s: float, flag_bits: int, valid: bool) -> None:
        """A sample was stepped: its time, its estimate's flag bits, whether the filter is initialised."""
        self.t_s = t_s
        self.bits = flag_bits
        self.valid = valid
        self._estimate = None

    @property
    def stepped(self) -> bool:
        return self.t_s == self.t_s      # not NaN: a sample was stepped

    @property
    def flags(self) -> EstimateFlags:
        f = estimate_flags(self.bits)
        return f if self.valid else _INITIALISING | f

    def snapshot(self) -> AttitudeEstimate:
        """The AttitudeEstimate of the sample stepped last (built at the first call after the step)."""
        e = self._estimate
        if e is None:
            e = self._estimate = self._build(self.t_s, self.bits, self.valid)
        return e

    def freeze(self) -> None:
        """Build the snapshot now if a sample was stepped and it is not built yet: the estimator is about to
        change something the builder reads."""
        if self._estimate is None and self.t_s == self.t_s:
            self.snapshot()

    def __getattr__(self, name: str):
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self.snapshot(), name)
