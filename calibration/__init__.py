"""ahrsd.calibration: sensor error models, the calibration store, and the bench/field calibrations.

At the top, what the daemon runs: the parameter models and `apply()` (`models`), the store and its atomic
file writes (`store`, `atomic_file`), the field magnetometer session (`field`) with ArduPilot's limits and
units (`ardupilot_compass`) and the fixed-yaw calibration (`fixed_yaw`); the Allan analysis (`allan*`).
The fits are in subpackages that never import the runtime modules: `mag/` (magnetometer) and `inertial/`
(accelerometer, gyroscope). Figures are drawn by the CLI (`ahrsd.cli.plots`).

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
