"""A magnetometer calibration's true heading error on a simulated sensor (truth via scipy)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def heading_error_on_other_attitudes_deg(model, stream) -> np.ndarray:
    """The calibration on the noise-free raw field of the same sensor at every 10° of heading, roll and pitch
    in ±8°, tilt-compensated with the true tilt, against the true heading (scipy only)."""
    f = stream.earth_field
    y, p, r = (a.ravel() for a in np.meshgrid(np.radians(np.arange(0, 360, 10.0)), np.radians([-8.0, 0.0, 8.0]),
                                              np.radians([-8.0, 0.0, 8.0]), indexing="ij"))
    raw = Rotation.from_euler("ZYX", np.column_stack([y, p, r])).inv().apply(f.ned_ut) @ stream.errors.soft_iron.T \
        + stream.errors.hard_iron_ut
    level = Rotation.from_euler("ZYX", np.column_stack([0 * y, p, r])).apply(model.apply(raw))
    psi = np.arctan2(-level[:, 1], level[:, 0]) + f.declination_rad
    return np.degrees(np.angle(np.exp(1j * (psi - y))))
