"""MAV_CMD_FIXED_MAG_CAL_YAW: hard iron from one still reading at a known heading, soft iron kept."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .ardupilot_compass import UT_TO_MGAUSS
from .models import MagModel

if TYPE_CHECKING:  # pragma: no cover
    from ahrsd.core.wmm import EarthField


@dataclass(frozen=True)
class FixedYawResult:
    model: MagModel
    expected_body_ut: np.ndarray
    measured_raw_ut: np.ndarray
    field_mismatch_ut: float  # | |W(raw − h_old)| − |B_wmm| |: how far the old model was from the WMM strength
    message: str


def fixed_yaw_calibration(
    true_heading_deg: float,
    reference: "EarthField",
    roll_rad: float,
    pitch_rad: float,
    raw_mag_ut: np.ndarray,
    current: MagModel,
) -> FixedYawResult:
    """MAV_CMD_FIXED_MAG_CAL_YAW: the vehicle points at a known TRUE heading; the expected body-frame field
    is the WMM field (true-north NED) rotated by roll, pitch and that heading. New hard iron h so that
    W · (raw − h) equals it, with W — the soft-iron terms — KEPT (ArduPilot's mag_cal_fixed_yaw resets them
    to identity, which throws away a good soft-iron calibration: Compass::mag_cal_fixed_yaw in ArduPilot's
    libraries/AP_Compass/AP_Compass_Calibration.cpp).

    raw_mag_ut: the raw field averaged over a short still period (µT, sensor frame; roll, pitch and heading
    are those of the sensor axes — daemon.magcal.sensor_attitude maps the body attitude through the mounting).
    """
    from scipy.spatial.transform import Rotation

    raw = np.asarray(raw_mag_ut, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(raw)) or not math.isfinite(true_heading_deg):
        raise ValueError("fixed-yaw calibration needs a finite heading and magnetometer reading")
    c_bn = Rotation.from_euler("ZYX", [math.radians(true_heading_deg), pitch_rad, roll_rad]).as_matrix()
    expected = c_bn.T @ reference.ned_ut
    w = np.asarray(current.soft_iron, dtype=np.float64)
    h = raw - np.linalg.solve(w, expected)
    before = float(np.linalg.norm(current.apply(raw)))
    mismatch = abs(before - reference.total_ut)
    msg = (
        f"fixed-yaw cal at {true_heading_deg:.1f} deg true: offsets "
        f"{np.round(-h * UT_TO_MGAUSS).astype(int).tolist()} mG, soft iron kept"
    )
    return FixedYawResult(MagModel(h, w), expected, raw, mismatch, msg)
