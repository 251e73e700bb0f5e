"""One shape for every magnetometer fit: `MagFitInput` in, `MagFitResult` out (`fit.fit_mag` dispatches).

Every method returns a `MagFitResult` whose `model` maps raw µT to calibrated µT
(m = soft_iron · (raw − hard_iron)). When a method cannot support its model with the data (too few samples,
poor coverage, ill-conditioned regression, non-physical solution), it does not raise: it returns
`refused="<reason a person can act on>"` and the identity model, which must not be used.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..models import MagModel, _jsonable


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


@dataclass(frozen=True)
class MagFitResult:
    """A magnetometer fit. `residual_rms_ut`: RMS of |calibrated| − reference magnitude over the samples
    used (of the rejected fit when refused after fitting; NaN when no fit was made). `quality`:
    method-specific checks (n_used, coverage, condition number, parameter 1σ, ...; a refused fit's model
    is under quality['rejected_model']). `refused`: None when the model is usable, else why not."""

    model: MagModel
    residual_rms_ut: float
    method: str
    quality: dict = field(default_factory=dict)
    refused: str | None = None
    # (roll_rad, pitch_rad, used) per input row when the fit levelled with an attitude other than the
    # accelerometer's (the aided levelling), so a figure draws the field as the fit saw it; not in the JSON
    levelling: tuple | None = field(default=None, compare=False, repr=False)

    @property
    def ok(self) -> bool:
        return self.refused is None

    def to_json_dict(self) -> dict:
        """The public `ahrsd calibrate mag --json` keys (plus method, quality and refused)."""
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


def finite_rows(mag_ut: np.ndarray) -> np.ndarray:
    return np.all(np.isfinite(mag_ut), axis=1)
