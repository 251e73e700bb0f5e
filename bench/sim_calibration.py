"""A magnetometer calibration in the state directory of a test's or a benchmark's `ahrsd run --sim`: without GNSS
the daemon sends a heading only on a calibration that states its predicted heading error
(estimator/calibration_heading.py), as a vehicle's must.

`save_mag_calibration(state_dir)`: the identity model (the made-up samples of the in-process rig have no iron);
`save_mag_calibration(state_dir, sim_chip_mag_model())`: the exact model of the simulated chip's own turn-on
magnetometer errors (`ahrsd run --sim static`, seed 0, no vehicle iron; another scenario's adds its vehicle iron),
as `calibrate mag` would find it."""

from __future__ import annotations

import numpy as np

HEADING_STD_DEG = 0.5    # what the calibration states (calibration/heading_trust.py): heading-dependent 1σ
OFFSET_STD_DEG = 0.2     # ... and the constant offset's 1σ


def sim_chip_mag_model(scenario: str = "static", seed: int = 0):
    """The MagModel that removes the magnetometer errors of `ahrsd run --sim SCENARIO` (drivers/simulated.py: errors
    "adis16405" drawn from `seed`, and the scenario's vehicle iron, e.g. level-turns')."""
    from ahrsd.calibration.models import MagModel
    from ahrsd.simulation import open_stream

    err = open_stream(scenario, seed=seed).errors
    return MagModel(np.asarray(err.hard_iron_ut, float), np.linalg.inv(err.soft_iron))


def save_mag_calibration(state_dir, model=None) -> None:
    """Save a calibration whose magnetometer model is `model` (identity by default), stating HEADING_STD_DEG and
    OFFSET_STD_DEG, in `state_dir`."""
    from ahrsd.calibration.models import Calibration, MagModel
    from ahrsd.calibration.store import CalibrationStore

    CalibrationStore(state_dir).save(Calibration.identity().with_sensor(
        "mag", model if model is not None else MagModel.identity(), method="test",
        heading_std_deg=HEADING_STD_DEG, offset_std_deg=OFFSET_STD_DEG))
