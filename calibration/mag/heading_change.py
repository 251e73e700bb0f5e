"""How far replacing one magnetometer model by another moves the tilt-compensated heading, and the models
in between (for a calibration change that is phased in)."""

from __future__ import annotations

import math

import numpy as np

from ahrsd.core.angles import tilt_compensated_heading_rad, wrap_pi

from ..models import MagModel


def max_heading_change_deg(old: MagModel, new: MagModel, field_body_ut: np.ndarray, roll_rad: float,
                           pitch_rad: float, n_headings: int = 36) -> float:
    """Largest change of the tilt-compensated heading that replacing `old` by `new` causes, over a full turn
    at the given roll/pitch. `field_body_ut` is the current calibrated field (its levelled horizontal
    magnitude and vertical component are kept, its direction swept through `n_headings` headings); the raw
    readings are those the new model maps onto those fields (the new model taken as the truth)."""
    from scipy.spatial.transform import Rotation

    b = np.asarray(field_body_ut, dtype=np.float64).reshape(3)
    tilt = Rotation.from_euler("YX", [pitch_rad, roll_rad])       # body -> level frame (no yaw)
    level = tilt.apply(b)
    h, down = math.hypot(level[0], level[1]), level[2]
    psi = np.linspace(0.0, 2 * np.pi, n_headings, endpoint=False)
    # a field at magnetic heading psi has level-frame components (H cos psi, -H sin psi, down)
    fields_level = np.column_stack([h * np.cos(psi), -h * np.sin(psi), np.full_like(psi, down)])
    fields_body = tilt.inv().apply(fields_level)
    raw = fields_body @ np.linalg.inv(new.soft_iron).T + new.hard_iron_ut
    h_old = tilt_compensated_heading_rad(old.apply(raw), roll_rad, pitch_rad)
    h_new = tilt_compensated_heading_rad(new.apply(raw), roll_rad, pitch_rad)
    return float(np.degrees(np.max(np.abs(wrap_pi(h_new - h_old)))))


def blend_models(old: MagModel, new: MagModel, alpha: float) -> MagModel:
    """The model a fraction `alpha` (0..1) of the way from `old` to `new` (hard and soft iron interpolated)."""
    a = min(1.0, max(0.0, float(alpha)))
    return MagModel((1 - a) * old.hard_iron_ut + a * new.hard_iron_ut, (1 - a) * old.soft_iron + a * new.soft_iron)
