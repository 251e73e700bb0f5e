"""One shape for every magnetometer fit: `MagFitInput` in, `MagFitResult` out, `fit_mag` dispatches.

Methods:
  ellipsoid     full 9-parameter ellipsoid (algebraic guess + Levenberg–Marquardt)      calibration/ellipsoid.py
  two-step      thesis §10.1.1, 6 parameters: hard iron + per-axis scale                 calibration/mag_twostep.py
  three-step    thesis §10.1.2, 9 parameters: + non-orthogonality                        calibration/mag_threestep.py
  backstepping  seed 002, for vehicles that cannot be tumbled                            calibration/backstepping.py

Every method returns a `MagFitResult` whose `model` maps raw µT to calibrated µT
(m = soft_iron · (raw − hard_iron)). When a method cannot support its model with the data (too few samples,
poor coverage, ill-conditioned regression, non-physical solution), it does not raise: it returns
`refused="<reason a person can act on>"` and the identity model, which must not be used.
"""

from __future__ import annotations

import importlib
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from .models import MagModel

if TYPE_CHECKING:  # pragma: no cover
    from ahrsd.estimator.wmm import EarthField

METHODS = ("ellipsoid", "two-step", "three-step", "backstepping")


def _as_block(value, name: str, n: int | None) -> np.ndarray:
    arr = np.array(value, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name}: expected shape (n, 3), got {arr.shape}")
    if n is not None and arr.shape[0] != n:
        raise ValueError(f"{name}: {arr.shape[0]} rows but t_s has {n}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class MagFitInput:
    """Samples for a magnetometer fit, all in the sensor frame, one row per sample.

    t_s (n,) seconds; mag_ut (n, 3) raw µT; accel_m_s2 (n, 3) specific force (optional: tilt, levelled
    turns); gyro_rad_s (n, 3) (optional: rotation between samples); heading_ref_deg (n,) an independent
    heading reference such as GNSS course or a known fixed yaw (optional, NaN where unknown).
    Rows with a non-finite magnetometer value are dropped by the fits (counted in `quality`).
    """

    t_s: np.ndarray
    mag_ut: np.ndarray
    accel_m_s2: np.ndarray | None = None
    gyro_rad_s: np.ndarray | None = None
    heading_ref_deg: np.ndarray | None = None

    def __post_init__(self) -> None:
        t = np.array(self.t_s, dtype=np.float64).reshape(-1)
        t.setflags(write=False)
        n = t.shape[0]
        object.__setattr__(self, "t_s", t)
        object.__setattr__(self, "mag_ut", _as_block(self.mag_ut, "mag_ut", n))
        for name in ("accel_m_s2", "gyro_rad_s"):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, _as_block(getattr(self, name), name, n))
        if self.heading_ref_deg is not None:
            h = np.array(self.heading_ref_deg, dtype=np.float64).reshape(-1)
            if h.shape[0] != n:
                raise ValueError(f"heading_ref_deg: {h.shape[0]} values but t_s has {n}")
            h.setflags(write=False)
            object.__setattr__(self, "heading_ref_deg", h)

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    def select(self, mask: np.ndarray) -> "MagFitInput":
        """The rows where `mask` is true (boolean (n,) or index array)."""
        pick = (lambda a: None if a is None else a[mask])
        return MagFitInput(self.t_s[mask], self.mag_ut[mask], pick(self.accel_m_s2), pick(self.gyro_rad_s),
                           pick(self.heading_ref_deg))

    @classmethod
    def from_recording(cls, recording) -> "MagFitInput":
        """From an `ahrsd.drivers.recording.Recording` (or anything with t_s, mag_ut, accel_m_s2, gyro_rad_s)."""
        return cls(recording.t_s, recording.mag_ut, getattr(recording, "accel_m_s2", None),
                   getattr(recording, "gyro_rad_s", None))


@dataclass(frozen=True)
class MagFitResult:
    """A magnetometer fit. `residual_rms_ut`: RMS of |calibrated| − reference magnitude over the samples
    used (NaN when refused). `quality`: method-specific checks (n_used, coverage, condition number, ...).
    `refused`: None when the model is usable, else why not."""

    model: MagModel
    residual_rms_ut: float
    method: str
    quality: dict = field(default_factory=dict)
    refused: str | None = None

    @property
    def ok(self) -> bool:
        return self.refused is None

    def to_json_dict(self) -> dict:
        """The public `ahrsd calibrate mag --json` keys (plus method, quality and refused)."""
        from .models import _jsonable

        return {
            "method": self.method,
            "hard_iron_ut": self.model.hard_iron_ut.tolist(),
            "soft_iron": self.model.soft_iron.tolist(),
            "residual_rms_ut": _jsonable(self.residual_rms_ut),
            "quality": _jsonable(self.quality),
            "refused": self.refused,
        }


def refuse(method: str, reason: str, **quality: Any) -> MagFitResult:
    """A refused result (identity model, NaN residual)."""
    return MagFitResult(MagModel.identity(), math.nan, method, dict(quality), reason)


# ---------------------------------------------------------------------------------------------- helpers


def finite_rows(mag_ut: np.ndarray) -> np.ndarray:
    return np.all(np.isfinite(mag_ut), axis=1)


def magnitude_residuals(model: MagModel, mag_ut: np.ndarray, field_ut: float) -> np.ndarray:
    """|model(raw)| − field_ut per sample (µT)."""
    return np.linalg.norm(model.apply(mag_ut), axis=1) - field_ut


def direction_coverage(unit_vectors: np.ndarray, n_bins: int = 26) -> float:
    """Fraction (0…1) of `n_bins` evenly spread directions that have a sample within ~38° of them
    (the 26 face/edge/corner directions of a cube). A full tumble gives 1.0, a level turn ≈ 0.3."""
    dirs = _cube_directions()
    u = np.asarray(unit_vectors, dtype=np.float64)
    if u.size == 0:
        return 0.0
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    cos_limit = math.cos(math.radians(38.0))
    # Dot products in chunks so hours of data do not build a huge matrix.
    hit = np.zeros(len(dirs), dtype=bool)
    for start in range(0, u.shape[0], 20000):
        hit |= np.any(u[start:start + 20000] @ dirs.T > cos_limit, axis=0)
    return float(hit.mean())


def _cube_directions() -> np.ndarray:
    d = [(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1) if (i, j, k) != (0, 0, 0)]
    d = np.array(d, dtype=np.float64)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def reference_magnitude_ut(reference: "EarthField | None", mag_ut: np.ndarray, field_ut: float | None = None) -> tuple[float, str]:
    """The field magnitude a fit scales to: explicit `field_ut`, else WMM |F|, else the mean raw norm
    (then the result has the right shape but only approximately the right scale). Returns (µT, source)."""
    if field_ut is not None:
        return float(field_ut), "given"
    if reference is not None:
        return float(reference.total_ut), "wmm"
    return float(np.mean(np.linalg.norm(mag_ut, axis=1))), "mean raw norm (no reference field given)"


# ---------------------------------------------------------------------------------------------- dispatch


def _resolve(method: str) -> Callable[..., MagFitResult]:
    if method == "ellipsoid":
        from .ellipsoid import fit_ellipsoid

        return fit_ellipsoid
    if method == "two-step":
        from .mag_twostep import fit_two_step

        return fit_two_step
    if method == "three-step":
        from .mag_threestep import fit_three_step

        return fit_three_step
    if method == "backstepping":
        try:
            module = importlib.import_module("ahrsd.calibration.backstepping")
        except ModuleNotFoundError as exc:
            if exc.name != "ahrsd.calibration.backstepping":
                raise
            raise NotImplementedError(
                "the backstepping magnetometer calibration (calibration/backstepping.py) is not installed"
            ) from None
        fn = getattr(module, "fit_backstepping", None)
        if fn is None:
            raise NotImplementedError("ahrsd.calibration.backstepping has no fit_backstepping()")
        return fn
    raise ValueError(f"unknown magnetometer calibration method {method!r}; choose one of {', '.join(METHODS)}")


def fit_mag(method: str, data: MagFitInput, reference: "EarthField | None" = None, **options) -> MagFitResult:
    """Fit the magnetometer model with `method` (one of METHODS). `reference` is the WMM field at the
    calibration site (`ahrsd.estimator.wmm.earth_field`), used for the magnitude (and, by methods that
    need it, the inclination). Options go to the method."""
    if not isinstance(data, MagFitInput):
        raise TypeError(f"data must be a MagFitInput, got {type(data).__name__}")
    return _resolve(method)(data, reference, **options)
