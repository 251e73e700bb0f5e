"""The accelerometer calibration aligned to the unit's housing from its six faces (`calibrate accel
--align-to-faces`, opt-in).

The multi-position fit (`accel.py`) sees only the gravity norm, so a rotation of the calibrated triad is
invisible to it: it fixes the frame by the accelerometer's own x axis. That frame is off the housing by the
triad's rotation (part of the sensor's axis-to-package alignment error), and so is any levelling done in it:
the horizon the estimators hold, and the frame a magnetometer calibration levelled by them is fitted in.
Through the magnetic dip I a tilt error δ moves a tilt-compensated heading by up to δ·tan I (3.5 δ at I = 74°).

When the unit rests flat on each of its six faces on a level surface, gravity is known in the housing frame
there: +g along the axis pointing up. The rotation R that best maps the calibrated face readings c_i onto
those directions a_i (Wahba's problem, min Σ‖a_i − R ĉ_i‖², by the project's SVD solver: estimator/wahba.py,
Markley 1988) is folded into the matrix: f = R·L·(f̃ − b − q∘f̃²). Bias, scale, non-orthogonality and the
quadratic terms are unchanged, and so is |f|.

The surface must be level (a machinist's level to about 0.02°) and each face must sit flat on it. A surface
tilt τ puts each face's reading up to τ off its axis, in a direction that turns with the unit as it is placed;
the six faces then disagree after the best rotation, and the alignment is refused above
MAX_FACE_RESIDUAL_DEG. A tilt that happened to map onto one rotation in every placement cannot be seen.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ahrsd.estimator import wahba
from ahrsd.estimator.rotations import quat_log

from .accel import AccelFitResult
from ..models import AccelModel

FACE_AXES = np.vstack([np.eye(3), -np.eye(3)])        # the up direction in housing axes, per face
FACE_NAMES = ("X up", "Y up", "Z up", "X down", "Y down", "Z down")
FACE_TOLERANCE_DEG = 5.0        # a still position this close to a face axis is taken as resting on that face
MAX_FACE_RESIDUAL_DEG = 0.1     # faces disagreeing by more (RMS) after the best rotation: not level, or not flat


def face_directions(model: AccelModel, position_means_m_s2: np.ndarray,
                    tolerance_deg: float = FACE_TOLERANCE_DEG) -> dict[int, np.ndarray]:
    """Face index (into FACE_AXES) → the unit direction the calibrated accelerometer reads resting on that face
    (the mean of every position within `tolerance_deg` of it)."""
    cal = model.apply(np.asarray(position_means_m_s2, dtype=float).reshape(-1, 3))
    unit = cal / np.linalg.norm(cal, axis=1, keepdims=True)
    cos_tol = math.cos(math.radians(tolerance_deg))
    found = {}
    for k, axis in enumerate(FACE_AXES):
        near = unit[unit @ axis >= cos_tol]
        if len(near):
            mean = near.mean(axis=0)
            found[k] = mean / np.linalg.norm(mean)
    return found


def align_to_faces(result: AccelFitResult, position_means_m_s2: np.ndarray,
                   max_residual_deg: float = MAX_FACE_RESIDUAL_DEG) -> AccelFitResult:
    """`result` with its matrix rotated into the housing frame of the faces, or refused with the reason (the
    unit was not on all six faces, or they disagree: the surface is not level or the unit not flat on it).
    A refused `result` is returned as it is. Adds quality["face_alignment"]: the rotation applied (deg, and
    as a rotation vector), and each face's angle from its axis after it."""
    if not result.ok:
        return result
    found = face_directions(result.model, position_means_m_s2)
    missing = [FACE_NAMES[k] for k in range(6) if k not in found]
    if missing:
        return dataclasses.replace(result, refused=(
            "--align-to-faces needs the unit resting flat on each of its six faces (within "
            f"{FACE_TOLERANCE_DEG:g}° of an axis); missing: {', '.join(missing)}"))
    faces = sorted(found)
    observed = np.array([found[k] for k in faces])
    axes = FACE_AXES[faces]
    solution = wahba.svd(observed, axes)     # the rotation calibrated frame → housing
    rot = solution.dcm
    after = observed @ rot.T
    residual_deg = np.degrees(np.arccos(np.clip(np.sum(after * axes, axis=1), -1.0, 1.0)))
    rms_deg = float(np.sqrt(np.mean(residual_deg**2)))
    rotvec_deg = np.degrees(quat_log(solution.q_wxyz))
    angle_deg = float(np.linalg.norm(rotvec_deg))
    quality = {**result.quality, "face_alignment": {
        "rotation_deg": angle_deg, "rotation_vector_deg": rotvec_deg.tolist(),
        "face_residual_rms_deg": rms_deg, "face_residuals_deg": dict(zip([FACE_NAMES[k] for k in faces],
                                                                         residual_deg.tolist()))}}
    if not rms_deg <= max_residual_deg:
        return dataclasses.replace(result, quality=quality, refused=(
            f"--align-to-faces: the six faces disagree by {rms_deg:.3f}° RMS after the best rotation (limit "
            f"{max_residual_deg:g}°): the surface is not level or the unit does not sit flat on it; level the "
            "surface to about 0.02° and record again, or calibrate without --align-to-faces"))
    model = AccelModel(result.model.bias_m_s2, rot @ result.model.matrix, result.model.quadratic)
    return dataclasses.replace(result, model=model, quality=quality)
