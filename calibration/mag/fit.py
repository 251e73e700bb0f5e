"""The magnetometer fit dispatcher: `fit_mag(method, data, reference)` runs one of METHODS.

Methods:
  ellipsoid     full 9-parameter ellipsoid (algebraic guess + Levenberg–Marquardt)      mag/ellipsoid.py
  two-step      thesis,         6 parameters: hard iron + per-axis scale                 mag/two_step.py
  three-step    thesis,         9 parameters: + non-orthogonality                        mag/three_step.py
  backstepping  Nourmohammadi & Sabet 2022, for vehicles that cannot be tumbled         mag/backstepping.py

The shared input/result types live in `fit_types`; the methods import those, never this module, so the
dispatcher can import every method at the top.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Callable

from .backstepping import fit_backstepping
from .ellipsoid import fit_ellipsoid
from .fit_types import MagFitInput, MagFitResult
from .three_step import fit_three_step
from .two_step import fit_two_step

if TYPE_CHECKING:  # pragma: no cover
    from ahrsd.core.wmm import EarthField

METHODS = ("ellipsoid", "two-step", "three-step", "backstepping")
_FITS: dict[str, Callable[..., MagFitResult]] = {
    "ellipsoid": fit_ellipsoid,
    "two-step": fit_two_step,
    "three-step": fit_three_step,
    "backstepping": fit_backstepping,
}


def fit_mag(method: str, data: MagFitInput, reference: "EarthField | None" = None, **options) -> MagFitResult:
    """Fit the magnetometer model with `method` (one of METHODS). `reference` is the WMM field at the
    calibration site (`ahrsd.core.wmm.earth_field`), used for the magnitude (and, by methods that
    need it, the inclination). Options go to the method."""
    if not isinstance(data, MagFitInput):
        raise TypeError(f"data must be a MagFitInput, got {type(data).__name__}")
    if method not in _FITS:
        raise ValueError(f"unknown magnetometer calibration method {method!r}; choose one of {', '.join(METHODS)}")
    return _FITS[method](data, reference, **options)
