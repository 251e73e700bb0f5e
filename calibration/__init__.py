"""ahrsd.calibration: sensor error models, the calibration store, and the bench/field calibrations.

Light imports only here (numpy); the fitting modules (scipy) are imported where they are used.
"""

from .models import (
    SCHEMA_VERSION,
    AccelModel,
    Calibration,
    GyroModel,
    InvalidCalibrationError,
    MagModel,
)

__all__ = ["SCHEMA_VERSION", "AccelModel", "Calibration", "GyroModel", "InvalidCalibrationError", "MagModel"]
