"""The accelerometer calibration aligned to the housing from the six faces (calibration/inertial/accel_alignment.py).

Truth is the simulator's own sensor model, raw = M·f + b (SensorErrors.accel_matrix, accel_bias_m_s2): the
exact calibration maps raw back to the housing-frame specific force f, rotation included, which the
gravity-norm fit alone cannot see. The reported rotation is checked against scipy's `Rotation.as_rotvec`.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.calibration.inertial.accel_alignment import FACE_AXES, align_to_faces
from ahrsd.calibration.inertial.accel import fit_accel
from ahrsd.simulation import DEFAULT_SITE, SensorErrors

from support.accel_positions import up_vectors

G = DEFAULT_SITE.gravity_m_s2
MEAN_NOISE_M_S2 = 0.3e-3 * 9.80665   # one 10-s position mean: white noise and in-run instability (0.3 mg)


def position_means(errs: SensorErrors, ups: np.ndarray, seed: int, tilt_deg: float = 0.0) -> np.ndarray:
    """Mean raw specific force of each still position; `tilt_deg`: each position's true up direction is that far
    off the nominal one, in a random direction (a surface that is not level, the unit turned on it at random)."""
    rng = np.random.default_rng(seed)
    true_up = []
    for u in ups:
        perp = np.cross(u, rng.normal(size=3))
        true_up.append(Rotation.from_rotvec(perp / np.linalg.norm(perp) * math.radians(tilt_deg)).apply(u))
    f = G * np.array(true_up)
    return f @ errs.accel_matrix.T + errs.accel_bias_m_s2 + rng.normal(0.0, MEAN_NOISE_M_S2, f.shape)


def frame_rotation_deg(model, errs: SensorErrors) -> float:
    """The rotation between the calibrated frame and the housing: the calibration's total error A·M (I when
    exact) less its symmetric part (scale, non-orthogonality), by the polar decomposition A·M = R·S."""
    u, _, vt = np.linalg.svd(model.matrix @ errs.accel_matrix)
    return float(np.degrees(Rotation.from_matrix(u @ vt).magnitude()))


@pytest.mark.parametrize("seed", [3, 7, 12])
def test_faces_on_a_level_surface_bring_the_calibration_into_the_housing_frame(seed):
    errs = SensorErrors.adis16405(seed=seed)
    ups = up_vectors()[:14]                  # the guided procedure: six faces, eight corners
    means = position_means(errs, ups, seed)
    plain = fit_accel(means, G)
    aligned = align_to_faces(plain, means)
    assert aligned.ok, aligned.refused
    before, after = frame_rotation_deg(plain.model, errs), frame_rotation_deg(aligned.model, errs)
    print(f"seed {seed}: calibrated frame {before:.3f}° from the housing by the norm fit alone, {after:.3f}° aligned")
    assert before > 0.05          # the triad's rotation, which the norm cannot see
    assert after < 0.02           # what 0.3 mg of noise on each face leaves
    # The norm fit is not undone: |f| is the same, the bias untouched.
    f_raw = means[6:]
    np.testing.assert_allclose(np.linalg.norm(aligned.model.apply(f_raw), axis=1),
                               np.linalg.norm(plain.model.apply(f_raw), axis=1), rtol=1e-12)
    np.testing.assert_array_equal(aligned.model.bias_m_s2, plain.model.bias_m_s2)
    fa = aligned.quality["face_alignment"]
    assert fa["face_residual_rms_deg"] < 0.06 and len(fa["face_residuals_deg"]) == 6
    # The reported rotation is the one applied: R = aligned · plain⁻¹.
    rot = aligned.model.matrix @ np.linalg.inv(plain.model.matrix)
    np.testing.assert_allclose(Rotation.from_matrix(rot).as_rotvec(degrees=True), fa["rotation_vector_deg"],
                               atol=1e-9)
    assert fa["rotation_deg"] == pytest.approx(np.linalg.norm(fa["rotation_vector_deg"]), abs=1e-9)


def test_a_missing_face_is_refused_by_name():
    errs = SensorErrors.adis16405(seed=3)
    ups = np.array([u for u in up_vectors() if not np.allclose(u, [0.0, 1.0, 0.0])])   # never on "Y up"
    means = position_means(errs, ups, 3)
    res = align_to_faces(fit_accel(means, G), means)
    assert not res.ok and "missing: Y up" in res.refused


def test_a_surface_that_is_not_level_is_refused_not_folded_in():
    errs = SensorErrors.adis16405(seed=3)
    ups = up_vectors()[:14]
    level = align_to_faces(fit_accel(means := position_means(errs, ups, 3, tilt_deg=0.02), G), means)
    assert level.ok, level.refused
    tilted_means = position_means(errs, ups, 3, tilt_deg=0.3)
    tilted = align_to_faces(fit_accel(tilted_means, G), tilted_means)
    assert not tilted.ok and "not level" in tilted.refused
    assert tilted.quality["face_alignment"]["face_residual_rms_deg"] > 0.1


def test_face_axes_are_the_six_signed_axes():
    assert sorted(map(tuple, FACE_AXES.astype(int).tolist())) == sorted(
        [tuple(s * np.eye(3, dtype=int)[i]) for i in range(3) for s in (1, -1)])


def test_each_face_twice_turned_half_round_cancels_a_tilted_surface():
    """On a surface tilted by τ, turning the unit 180° about the vertical on the same face reverses the tilt's
    component in the housing frame, so the mean of the pair lies on the axis (to first order) and the
    alignment is accepted and right."""
    errs = SensorErrors.adis16405(seed=7)
    tilt = Rotation.from_rotvec(np.radians([0.25, -0.2, 0.0]))      # the surface: 0.32° off level
    half_turn = Rotation.from_rotvec([0.0, 0.0, math.pi])
    rng = np.random.default_rng(5)
    ups = []
    for axis in FACE_AXES:
        # The unit resting on the face whose outward normal is −axis (axis up), at a random heading on the surface.
        rest = Rotation.align_vectors([[0.0, 0.0, 1.0]], [axis])[0]            # housing → a level world frame
        rest = Rotation.from_rotvec([0.0, 0.0, rng.uniform(0, 2 * math.pi)]) * rest
        for placement in (rest, half_turn * rest):
            ups.append(placement.inv().apply(tilt.apply([0.0, 0.0, 1.0])))     # the surface's up, housing axes
    corners = up_vectors()[6:14]
    ups = np.vstack([ups, corners])
    means = position_means(errs, ups, 7)
    res = align_to_faces(fit_accel(means, G), means)
    assert res.ok, res.refused
    assert frame_rotation_deg(res.model, errs) < 0.02
    # One placement per face on the same surface is refused (the faces disagree).
    single = np.vstack([np.array(ups[:12])[::2], corners])
    single_means = position_means(errs, single, 7)
    assert not align_to_faces(fit_accel(single_means, G), single_means).ok
