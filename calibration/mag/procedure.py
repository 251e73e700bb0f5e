"""The magnetometer calibration procedure behind `ahrsd calibrate mag`: the steps in order, one call.

1. with an alignment recording (three-step only): the three-step magnitude fit, then the rotation C_m'^p from
   the levelled turns of the second recording (`alignment.fit_alignment`), folded into the final fit;
2. the fit itself: `fit.fit_mag(method)`, or, with GNSS fixes, the back-stepping fit levelled by the aided
   estimator (`backstepping_aided.fit_backstepping_aided`);
3. with a compass-swing table: the deviation card fitted to it and its constant folded in (`swing_table`).

A step that cannot be done raises `MagCalibrationError` with the reason; a fit that the data cannot support is
returned refused (`MagFitResult.refused`), as every fit does.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable, ContextManager

import numpy as np

from .alignment import fit_alignment, segment_level_turns
from .backstepping_aided import fit_backstepping_aided
from .fit import fit_mag
from .fit_types import MagFitInput, MagFitResult
from .swing import SwingFitError
from .swing_table import apply_swing_table

if TYPE_CHECKING:  # pragma: no cover
    from ahrsd.core.wmm import EarthField


class MagCalibrationError(ValueError):
    """A step of the procedure could not be done: `step` is "alignment", "gnss" or "swing-table"; the message
    says why."""

    def __init__(self, step: str, message: str):
        super().__init__(message)
        self.step = step


@dataclass(frozen=True)
class AlignmentRecording:
    """The levelled turns for the alignment step: sensor-frame gyro (rad/s), calibrated accelerometer (m/s²),
    raw magnetometer (µT), one row per sample, at `rate_hz`."""

    gyro_rad_s: np.ndarray
    accel_m_s2: np.ndarray
    mag_ut: np.ndarray
    rate_hz: float


@dataclass(frozen=True)
class GnssLevelling:
    """The GNSS fixes the aided estimator levels the back-stepping fit with, and its options
    (`backstepping_aided.fit_backstepping_aided`: accel_bias_sigma_m_s2, filter_overrides, ...)."""

    fixes: list
    options: dict = field(default_factory=dict)


@dataclass(frozen=True)
class SwingTable:
    """A compass-swing table (`swing.load_swing_table`) and where it came from (for the report)."""

    reference_deg: np.ndarray
    compass_deg: np.ndarray
    source: str


@dataclass(frozen=True)
class MagCalibration:
    result: MagFitResult
    notes: tuple[str, ...] = ()      # what the procedure did beyond the fit, one line each


def _no_progress(_description: str) -> ContextManager:
    return contextlib.nullcontext()


def calibrate_mag(method: str, data: MagFitInput, reference: "EarthField", *,
                  alignment: AlignmentRecording | None = None, gnss: GnssLevelling | None = None,
                  swing_table: SwingTable | None = None, fit_options: dict | None = None,
                  step: Callable[[str], ContextManager] = _no_progress) -> MagCalibration:
    """Run the procedure (module docstring) on `data` (sensor frame; accelerometer and gyro calibrated) at the
    site whose WMM field is `reference`. `step(description)` wraps each long step (a progress display)."""
    options = dict(fit_options or {})
    notes = []
    if alignment is not None:
        if method != "three-step":
            raise MagCalibrationError("alignment", "the alignment step goes with the three-step fit")
        with step(f"fitting (three-step) {len(data)} samples"):
            first = fit_mag("three-step", data, reference)
        if not first.ok:
            return MagCalibration(first, tuple(notes))
        with step("fitting the alignment"):
            turns = segment_level_turns(alignment.gyro_rad_s, alignment.accel_m_s2, alignment.mag_ut,
                                        alignment.rate_hz)
            aligned = fit_alignment(turns, first.model, reference.down_ut)
        if not aligned.ok:
            raise MagCalibrationError("alignment", f"alignment step refused: {aligned.refused}")
        options["alignment"] = aligned.rotation
        notes.append(f"alignment from {len(turns)} levelled turns, rotation "
                     f"{aligned.quality['rotation_angle_deg']:.2f}°")
    if gnss is not None:
        if method != "backstepping":
            raise MagCalibrationError("gnss", "GNSS levelling goes with the back-stepping fit")
        with step(f"fitting ({method}, levelled with GNSS) {len(data)} samples"):
            try:
                result = fit_backstepping_aided(data, gnss.fixes, reference, reference.declination_rad,
                                                **gnss.options, **options)
            except (ValueError, ModuleNotFoundError) as exc:
                raise MagCalibrationError("gnss", f"the aided estimator could not level the recording: {exc}") from None
    else:
        with step(f"fitting ({method}) {len(data)} samples"):
            result = fit_mag(method, data, reference, **options)
    if swing_table is not None and result.ok:
        try:
            result = apply_swing_table(result, swing_table.reference_deg, swing_table.compass_deg,
                                       swing_table.source)
        except SwingFitError as exc:
            raise MagCalibrationError("swing-table", f"swing table {swing_table.source}: {exc}") from None
    return MagCalibration(result, tuple(notes))
