"""ArduPilot's compass calibration conventions: its offsets/diag/offdiag model and the acceptance limits of
its CompassCalibrator (libraries/AP_Compass/CompassCalibrator.cpp, AP_Compass.cpp parameter defaults).

ArduPilot corrects a reading as m = scale_factor · S · (raw + offsets) with S symmetric and offsets in
mgauss; ahrsd's model is m = W · (raw − h) in µT. `to_ardupilot`/`from_ardupilot` convert between them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .models import MagModel

UT_TO_MGAUSS = 10.0  # 1 µT = 10 mgauss (1 gauss = 100 µT)

COMPASS_CAL_FIT_DEFAULT_MGAUSS = 16.0   # AP_COMPASS_CALIBRATION_FITNESS_DEFAULT (4 very strict ... 32 relaxed)
COMPASS_OFFS_MAX_MGAUSS = 1800.0        # COMPASS_OFFS_MAX default
RADIUS_MIN_MGAUSS, RADIUS_MAX_MGAUSS = 150.0, 950.0  # CompassCalibrator::fit_acceptable
DIAG_MIN, DIAG_MAX = 0.2, 5.0                          # CompassCalibrator::fit_acceptable
OFFDIAG_MAX = 1.0                                      # CompassCalibrator::fit_acceptable
MAX_SCALE_FACTOR = 1.5                  # COMPASS_MAX_SCALE_FACTOR: WMM radius check (BAD_RADIUS)


@dataclass(frozen=True)
class ArduPilotMagParams:
    """A magnetometer model in ArduPilot's terms: corrected = scale_factor · S · (raw + offsets), with S
    symmetric: diag = (S11, S22, S33), offdiag = (S12=S21, S13=S31, S23=S32) (CompassCalibrator::calc_residual,
    MAG_CAL_REPORT). Offsets in mgauss. `residual_rotation_deg`: the rotation part of a non-symmetric soft
    iron that ArduPilot's symmetric S cannot carry (reported separately, 0 for a symmetric model)."""

    ofs_mgauss: np.ndarray
    diag: np.ndarray
    offdiag: np.ndarray
    scale_factor: float = 1.0
    residual_rotation_deg: float = 0.0

    def matrix(self) -> np.ndarray:
        d, o = self.diag, self.offdiag
        return np.array([[d[0], o[0], o[1]], [o[0], d[1], o[2]], [o[1], o[2], d[2]]], dtype=np.float64)


def to_ardupilot(model: MagModel) -> ArduPilotMagParams:
    """Our m = W · (raw − h) [µT] in ArduPilot's convention m = S · (raw + o) [mgauss in, mgauss out].

    o = −h (converted to mgauss). W is split by the polar decomposition W = R · P (R a rotation, P symmetric
    positive definite); S = P is what ArduPilot can represent and scale_factor = 1 (W already maps to the
    true field strength). For a symmetric W (every ellipsoid fit) this is exact; otherwise the rotation angle
    of R is returned in `residual_rotation_deg` so it is not silently lost.
    """
    from scipy.linalg import polar

    w = np.asarray(model.soft_iron, dtype=np.float64)
    r, p = polar(w, side="right")  # w = r @ p
    if np.linalg.det(r) < 0:  # a reflection would mean a mirrored sensor axis: keep it in P, not R
        r, p = -r, -p
    angle = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(r) - 1.0) / 2.0))))
    p = (p + p.T) / 2
    return ArduPilotMagParams(
        ofs_mgauss=-np.asarray(model.hard_iron_ut, dtype=np.float64) * UT_TO_MGAUSS,
        diag=np.diag(p).copy(),
        offdiag=np.array([p[0, 1], p[0, 2], p[1, 2]]),
        scale_factor=1.0,
        residual_rotation_deg=angle,
    )


def from_ardupilot(ofs_mgauss, diag, offdiag, scale_factor: float = 1.0) -> MagModel:
    """ArduPilot's COMPASS_OFS/DIA/ODI/SCALE back to our model. scale_factor 0 means "not set" in ArduPilot
    (AP_Compass applies no scaling) and is read as 1."""
    sf = float(scale_factor) if scale_factor and math.isfinite(scale_factor) else 1.0
    s = ArduPilotMagParams(np.asarray(ofs_mgauss, float), np.asarray(diag, float), np.asarray(offdiag, float)).matrix()
    return MagModel(-np.asarray(ofs_mgauss, dtype=np.float64) / UT_TO_MGAUSS, sf * s)
