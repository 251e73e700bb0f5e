"""Sensor error models and the `Calibration` bundle the daemon applies to every sample (CONTRIBUTING.md).

All three sensors share one form, calibrated = matrix · (raw − bias):

- gyro:  ω = M_g · (ω̃ − b_g)                       (12 g-independent terms: bias, scale, misalignment)
- accel: f = M_a · (f̃ − b_a − k_nl ∘ f̃ ∘ f̃)          (bias, 3×3 scale/misalignment, quadratic)
- mag:   m = S · (m̃ − h)                              (hard iron h in µT, soft iron S a full 3×3)

The thesis's magnetometer form m = C_m'^p · T_m^m' · K⁻¹ · (m̃ − b) is the
special case built by `MagModel.from_thesis` (and taken apart again by `MagModel.to_thesis`).

Models are frozen; `apply` works on one vector (3,) or a block (n, 3). `Calibration.apply(sample)` is the
per-sample hot path in the daemon: it precomputes M·b so each sensor costs one mat-vec and one subtraction.
"""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass, field, replace
from typing import Any, Mapping

import numpy as np

from ahrsd.core.sample import ImuSample

_dot = np.dot

SCHEMA_VERSION = 1          # of Calibration.to_dict(); bump on any incompatible change
MAX_CONDITION_NUMBER = 1e6  # a calibration matrix worse than this is treated as singular (not invertible)


class InvalidCalibrationError(ValueError):
    """A calibration dictionary or model has missing keys, wrong shapes, non-finite or singular values."""


# ---------------------------------------------------------------------------------------------- helpers


def _vector3(value: Any, name: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidCalibrationError(f"{name}: not a vector of 3 numbers ({exc})") from None
    if arr.shape != (3,):
        raise InvalidCalibrationError(f"{name}: expected 3 numbers, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InvalidCalibrationError(f"{name}: non-finite value in {arr.tolist()}")
    arr.setflags(write=False)
    return arr


def _matrix3(value: Any, name: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidCalibrationError(f"{name}: not a 3×3 matrix of numbers ({exc})") from None
    if arr.shape != (3, 3):
        raise InvalidCalibrationError(f"{name}: expected a 3×3 matrix, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InvalidCalibrationError(f"{name}: non-finite value in {arr.tolist()}")
    cond = np.linalg.cond(arr)
    if not math.isfinite(cond) or cond > MAX_CONDITION_NUMBER:
        raise InvalidCalibrationError(f"{name}: singular matrix (condition number {cond:.3g})")
    arr.setflags(write=False)
    return arr


def _frozen(arr: np.ndarray) -> np.ndarray:
    arr = np.ascontiguousarray(arr, dtype=np.float64)
    arr.setflags(write=False)
    return arr


def _apply_affine(matrix: np.ndarray, offset: np.ndarray, raw: np.ndarray) -> np.ndarray:
    """matrix · raw − offset for raw (3,) or (n, 3)."""
    raw = np.asarray(raw, dtype=np.float64)
    if raw.ndim == 1:
        return matrix @ raw - offset
    return raw @ matrix.T - offset


def misalignment_matrix(alpha: Mapping[str, float] | None) -> np.ndarray:
    """The thesis's small-angle misalignment T (below), α_ij = rotation of sensor axis i about
    platform axis j, in rad. Keys: 'yz', 'zy', 'zx', 'xz', 'xy', 'yx' (missing ones are 0).

        T = [[1, −α_yz, α_zy], [α_xz, 1, −α_zx], [−α_xy, α_yx, 1]]
    """
    a = {k: 0.0 for k in ("yz", "zy", "zx", "xz", "xy", "yx")}
    for key, value in (alpha or {}).items():
        if key not in a:
            raise ValueError(f"unknown misalignment angle {key!r}; use one of {', '.join(a)}")
        a[key] = float(value)
    return np.array(
        [[1.0, -a["yz"], a["zy"]], [a["xz"], 1.0, -a["zx"]], [-a["xy"], a["yx"], 1.0]], dtype=np.float64
    )


# ---------------------------------------------------------------------------------------------- models


@dataclass(frozen=True, slots=True)
class GyroModel:
    """ω_calibrated = matrix · (ω_raw − bias_rad_s). `matrix` holds scale and misalignment (dimensionless)."""

    bias_rad_s: np.ndarray
    matrix: np.ndarray
    _offset: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        b = _vector3(self.bias_rad_s, "gyro.bias_rad_s")
        m = _matrix3(self.matrix, "gyro.matrix")
        object.__setattr__(self, "bias_rad_s", b)
        object.__setattr__(self, "matrix", m)
        object.__setattr__(self, "_offset", _frozen(m @ b))

    @classmethod
    def identity(cls) -> "GyroModel":
        return cls(np.zeros(3), np.eye(3))

    def apply(self, gyro_rad_s: np.ndarray) -> np.ndarray:
        return _apply_affine(self.matrix, self._offset, gyro_rad_s)

    def to_dict(self) -> dict:
        return {"bias_rad_s": self.bias_rad_s.tolist(), "matrix": self.matrix.tolist()}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "GyroModel":
        return cls(_require(d, "bias_rad_s", "gyro"), _require(d, "matrix", "gyro"))

    def __eq__(self, other: object) -> bool:
        return isinstance(other, GyroModel) and np.array_equal(self.bias_rad_s, other.bias_rad_s) and np.array_equal(
            self.matrix, other.matrix
        )

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True, slots=True)
class AccelModel:
    """f_calibrated = matrix · (f_raw − bias_m_s2 − quadratic ∘ f_raw²).

    `quadratic` (unit 1/(m/s²)) is the thesis's nonlinearity K_nl, per axis on that axis's own
    raw reading; `matrix` holds scale and misalignment (the thesis's T_a^P · diag(1/(1+δk))).
    """

    bias_m_s2: np.ndarray
    matrix: np.ndarray
    quadratic: np.ndarray = field(default_factory=lambda: np.zeros(3))
    _offset: np.ndarray = field(init=False, repr=False, compare=False)
    _has_quadratic: bool = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        b = _vector3(self.bias_m_s2, "accel.bias_m_s2")
        m = _matrix3(self.matrix, "accel.matrix")
        q = _vector3(self.quadratic, "accel.quadratic")
        object.__setattr__(self, "bias_m_s2", b)
        object.__setattr__(self, "matrix", m)
        object.__setattr__(self, "quadratic", q)
        object.__setattr__(self, "_offset", _frozen(m @ b))
        object.__setattr__(self, "_has_quadratic", bool(np.any(q != 0.0)))

    @classmethod
    def identity(cls) -> "AccelModel":
        return cls(np.zeros(3), np.eye(3), np.zeros(3))

    def apply(self, accel_m_s2: np.ndarray) -> np.ndarray:
        raw = np.asarray(accel_m_s2, dtype=np.float64)
        if self._has_quadratic:
            raw = raw - self.quadratic * raw * raw
        return _apply_affine(self.matrix, self._offset, raw)

    def to_dict(self) -> dict:
        return {
            "bias_m_s2": self.bias_m_s2.tolist(),
            "matrix": self.matrix.tolist(),
            "quadratic_s2_m": self.quadratic.tolist(),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "AccelModel":
        return cls(
            _require(d, "bias_m_s2", "accel"), _require(d, "matrix", "accel"), d.get("quadratic_s2_m", np.zeros(3))
        )

    def __eq__(self, other: object) -> bool:
        return (
            isinstance(other, AccelModel)
            and np.array_equal(self.bias_m_s2, other.bias_m_s2)
            and np.array_equal(self.matrix, other.matrix)
            and np.array_equal(self.quadratic, other.quadratic)
        )

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True, slots=True)
class ThesisMagParameters:
    """The thesis's magnetometer parameters: m = C_m'^p · T_m^m' · K⁻¹ · (m̃ − b).

    bias_ut: b (µT); scale: k (dimensionless gains, raw = k · true + b on an orthogonal sensor);
    alpha: the six α_ij (rad) of T_m^p; alignment: C_m'^p (rotation, identity when not determined).
    """

    bias_ut: np.ndarray
    scale: np.ndarray
    alpha: dict
    alignment: np.ndarray


@dataclass(frozen=True, slots=True)
class MagModel:
    """m_calibrated = soft_iron · (m_raw − hard_iron_ut). Units: µT in, µT out."""

    hard_iron_ut: np.ndarray
    soft_iron: np.ndarray
    _offset: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        h = _vector3(self.hard_iron_ut, "mag.hard_iron_ut")
        s = _matrix3(self.soft_iron, "mag.soft_iron")
        object.__setattr__(self, "hard_iron_ut", h)
        object.__setattr__(self, "soft_iron", s)
        object.__setattr__(self, "_offset", _frozen(s @ h))

    @classmethod
    def identity(cls) -> "MagModel":
        return cls(np.zeros(3), np.eye(3))

    @classmethod
    def from_thesis(
        cls,
        bias_ut,
        scale,
        alpha: Mapping[str, float] | None = None,
        alignment: np.ndarray | None = None,
    ) -> "MagModel":
        """The thesis's b/k/α form: m = C_m'^p · T · K⁻¹ · (m̃ − b).

        bias_ut: b (µT). scale: k = (k_x, k_y, k_z) gains. alpha: α_ij (rad, see `misalignment_matrix`);
        the three-step algorithm yields only 'yz', 'zy', 'zx' (T_m^m', upper triangular).
        alignment: C_m'^p from the alignment step (default identity).
        """
        k = np.asarray(scale, dtype=np.float64).reshape(3)
        if np.any(k <= 0) or not np.all(np.isfinite(k)):
            raise InvalidCalibrationError(f"mag scale factors must be positive and finite, got {k.tolist()}")
        c = np.eye(3) if alignment is None else np.asarray(alignment, dtype=np.float64).reshape(3, 3)
        return cls(np.asarray(bias_ut, dtype=np.float64), c @ misalignment_matrix(alpha) @ np.diag(1.0 / k))

    def to_thesis(self) -> ThesisMagParameters:
        """Take soft_iron apart into C_m'^p · T_m^m' · K⁻¹ (the three-step form and
        the alignment step).

        QR of soft_iron = Q·R with R upper triangular and positive diagonal: Q = C_m'^p, R = T_m^m' · K⁻¹,
        so k_i = 1/R_ii and T = R · K, whose upper entries give −α_yz, α_zy, −α_zx. Exact for small
        and large angles alike (T_m^m' is upper triangular by construction).
        """
        q, r = np.linalg.qr(self.soft_iron)
        signs = np.sign(np.diag(r))
        signs[signs == 0] = 1.0
        q = q * signs          # make diag(r) positive
        r = signs[:, None] * r
        k = 1.0 / np.diag(r)
        t = r @ np.diag(k)
        alpha = {"yz": -t[0, 1], "zy": t[0, 2], "zx": -t[1, 2], "xz": 0.0, "xy": 0.0, "yx": 0.0}
        return ThesisMagParameters(self.hard_iron_ut.copy(), k, alpha, q)

    def apply(self, mag_ut: np.ndarray) -> np.ndarray:
        return _apply_affine(self.soft_iron, self._offset, mag_ut)

    def to_dict(self) -> dict:
        return {"hard_iron_ut": self.hard_iron_ut.tolist(), "soft_iron": self.soft_iron.tolist()}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "MagModel":
        return cls(_require(d, "hard_iron_ut", "mag"), _require(d, "soft_iron", "mag"))

    def __eq__(self, other: object) -> bool:
        return (
            isinstance(other, MagModel)
            and np.array_equal(self.hard_iron_ut, other.hard_iron_ut)
            and np.array_equal(self.soft_iron, other.soft_iron)
        )

    __hash__ = None  # type: ignore[assignment]


def _require(d: Mapping[str, Any], key: str, where: str) -> Any:
    if not isinstance(d, Mapping):
        raise InvalidCalibrationError(f"{where}: expected a table/object, got {type(d).__name__}")
    if key not in d:
        raise InvalidCalibrationError(f"{where}: missing key {key!r}")
    return d[key]


def _jsonable(value: Any) -> Any:
    """Metadata → plain JSON types (numpy → lists/floats, non-finite floats → None, dates → ISO)."""
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, (np.bool_, bool)):
        return bool(value)
    if isinstance(value, (np.integer, int)):
        return int(value)
    if isinstance(value, (np.floating, float)):
        v = float(value)
        return v if math.isfinite(v) else None
    if isinstance(value, (_dt.date, _dt.datetime)):
        return value.isoformat()
    if value is None or isinstance(value, str):
        return value
    return str(value)


# ---------------------------------------------------------------------------------------------- bundle

SENSORS = ("gyro", "accel", "mag")


@dataclass(frozen=True, slots=True)
class Calibration:
    """The three sensor models plus metadata (sensor id, per-sensor date/method/residuals/temperature).

    metadata layout (free-form JSON, by convention): {"sensor_id": str, "schema_version": int,
    "gyro"|"accel"|"mag": {"method": str, "date": ISO str, "residual_rms": float, "temp_c": float, ...}}.
    """

    gyro: GyroModel = field(default_factory=GyroModel.identity)
    accel: AccelModel = field(default_factory=AccelModel.identity)
    mag: MagModel = field(default_factory=MagModel.identity)
    metadata: dict = field(default_factory=dict)
    _is_identity: bool = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        for name, cls in (("gyro", GyroModel), ("accel", AccelModel), ("mag", MagModel)):
            if not isinstance(getattr(self, name), cls):
                raise InvalidCalibrationError(f"{name}: expected {cls.__name__}, got {type(getattr(self, name)).__name__}")
        meta = _jsonable(dict(self.metadata or {}))
        meta["schema_version"] = SCHEMA_VERSION
        object.__setattr__(self, "metadata", meta)
        object.__setattr__(
            self,
            "_is_identity",
            self.gyro == GyroModel.identity() and self.accel == AccelModel.identity() and self.mag == MagModel.identity(),
        )

    @classmethod
    def identity(cls) -> "Calibration":
        return cls(metadata={"method": "identity"})

    @property
    def is_identity(self) -> bool:
        return self._is_identity

    def apply(self, sample: ImuSample) -> ImuSample:
        """The calibrated copy of `sample` (every other field unchanged)."""
        if self._is_identity:
            return sample
        gyro, accel, mag = self.apply_vectors(sample.gyro_rad_s, sample.accel_m_s2, sample.mag_ut)
        return ImuSample(sample.t_s, gyro, accel, mag, sample.temp_c, sample.supply_v, sample.flags,
                         sample.diag_stat, sample.counter)

    def apply_vectors(self, gyro_rad_s: np.ndarray, accel_m_s2: np.ndarray, mag_ut: np.ndarray):
        """The calibrated (gyro, accel, mag) of one sample's (3,) vectors, as new arrays. Runs once per sample."""
        g, a, m = self.gyro, self.accel, self.mag
        acc = accel_m_s2
        if a._has_quadratic:  # acc − q∘acc∘acc with one allocation
            t = a.quadratic * acc
            t *= acc
            np.subtract(acc, t, out=t)
            acc = t
        # np.dot then an in-place subtraction: one allocation per vector (faster than M @ v − o).
        gyro = _dot(g.matrix, gyro_rad_s)
        gyro -= g._offset
        accel = _dot(a.matrix, acc)
        accel -= a._offset
        mag = _dot(m.soft_iron, mag_ut)
        mag -= m._offset
        return gyro, accel, mag

    def apply_arrays(self, gyro_rad_s=None, accel_m_s2=None, mag_ut=None):
        """Vectorised form for recordings: each argument (n, 3) or None; returns a tuple in the same order."""
        return (
            None if gyro_rad_s is None else self.gyro.apply(gyro_rad_s),
            None if accel_m_s2 is None else self.accel.apply(accel_m_s2),
            None if mag_ut is None else self.mag.apply(mag_ut),
        )

    def with_sensor(self, sensor: str, model, **metadata) -> "Calibration":
        """A copy with one sensor's model replaced and its metadata section set (the other sensors kept)."""
        if sensor not in SENSORS:
            raise ValueError(f"unknown sensor {sensor!r}; choose one of {', '.join(SENSORS)}")
        meta = dict(self.metadata)
        section = {"date": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")}
        section.update(metadata)
        meta[sensor] = section
        return replace(self, **{sensor: model, "metadata": meta})

    def to_dict(self) -> dict:
        return {
            "schema_version": SCHEMA_VERSION,
            "gyro": self.gyro.to_dict(),
            "accel": self.accel.to_dict(),
            "mag": self.mag.to_dict(),
            "metadata": dict(self.metadata),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "Calibration":
        """Inverse of `to_dict`; raises `InvalidCalibrationError` naming the bad key."""
        if not isinstance(d, Mapping):
            raise InvalidCalibrationError(f"calibration: expected an object, got {type(d).__name__}")
        version = d.get("schema_version")
        if version != SCHEMA_VERSION:
            raise InvalidCalibrationError(
                f"unsupported calibration schema_version {version!r} (this ahrsd reads version {SCHEMA_VERSION})"
            )
        metadata = d.get("metadata", {})
        if not isinstance(metadata, Mapping):
            raise InvalidCalibrationError("metadata: expected an object")
        return cls(
            GyroModel.from_dict(_require(d, "gyro", "calibration")),
            AccelModel.from_dict(_require(d, "accel", "calibration")),
            MagModel.from_dict(_require(d, "mag", "calibration")),
            dict(metadata),
        )

    def __eq__(self, other: object) -> bool:
        return (
            isinstance(other, Calibration)
            and self.gyro == other.gyro
            and self.accel == other.accel
            and self.mag == other.mag
            and self.metadata == other.metadata
        )

    __hash__ = None  # type: ignore[assignment]
