"""Completion mask (AP_GeodesicGrid), ArduPilot report convention, fixed-yaw calibration, heading slew."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from ahrsd.calibration.ardupilot_compass import from_ardupilot, to_ardupilot
from ahrsd.calibration.fixed_yaw import fixed_yaw_calibration
from ahrsd.calibration.mag.geodesic_grid import (
    GEODESIC_MID_TRIANGLES,
    GEODESIC_TRIANGLES,
    completion_mask_bytes,
    geodesic_section,
    geodesic_sections,
    section_centres,
)
from ahrsd.core.angles import tilt_compensated_heading_rad
from ahrsd.daemon.heading_slew import HeadingSlew
from ahrsd.calibration.models import MagModel
from ahrsd.core.wmm import earth_field

G = (1 + math.sqrt(5)) / 2


def test_geodesic_sections_match_ardupilot_test_vectors():
    # libraries/AP_Math/tests/test_geodesic_grid.cpp "hardcoded_vectors" (the non-edge cases). Its third
    # vector, (-0.2667, 0.1667φ, 2.2667φ+0.1667) -> 71, is left out: it is 1·a + 0.1667·b + 1.2667·c of the
    # vertices of triangle 13 in the triangle table of the AP_GeodesicGrid.cpp we mirror, so it cannot lie
    # in triangle 17 (section 71) of that table.
    cases = [
        ((0.25 * G, -0.25 * (13 * G + 1), -1.25), 17),
        ((-0.875, 6.125 * G, -1.125 * G - 6.125), 34),
    ]
    got = geodesic_sections(np.array([c[0] for c in cases]))
    assert got.tolist() == [c[1] for c in cases]
    assert [geodesic_section(np.array(c[0])) for c in cases] == [c[1] for c in cases]   # the one-vector form


def test_geodesic_section_centroids_map_to_their_own_section():
    # the "MidVectors" case of the same ArduPilot test: the centroid of section i is in section i
    t, m = GEODESIC_TRIANGLES, GEODESIC_MID_TRIANGLES
    centroids = []
    for i in range(20):
        for a, b, c in ((m[i, 0], m[i, 1], m[i, 2]), (t[i, 0], m[i, 0], m[i, 2]), (m[i, 0], t[i, 1], m[i, 1]),
                        (m[i, 2], m[i, 1], t[i, 2])):
            centroids.append((a + b + c) / 3)
    assert geodesic_sections(np.array(centroids)).tolist() == list(range(80))
    assert geodesic_sections(section_centres()).tolist() == list(range(80))
    assert [geodesic_section(c) for c in centroids] == list(range(80))


def test_geodesic_zero_and_nan_vectors_have_no_section():
    assert geodesic_sections(np.array([[0.0, 0, 0], [np.nan, 1, 0]])).tolist() == [-1, -1]
    assert [geodesic_section(v) for v in ([0.0, 0, 0], [np.nan, 1, 0], [1.0, np.inf, 0])] == [-1, -1, -1]


def test_one_vector_lands_where_the_batch_puts_it():
    """The field session's per-sample form (geodesic_section) and the batch form agree everywhere: random
    directions at any scale, the 60 triangle vertices and edge midpoints (where two triangles share the
    direction: the batch takes the first), and directions within 1e-10 of those edges."""
    rng = np.random.default_rng(3)
    t = GEODESIC_TRIANGLES.reshape(-1, 3)
    edges = np.array([(a + b) / 2 for a in t for b in t if np.linalg.norm(a - b) < 2.1])
    v = np.concatenate([rng.normal(size=(3000, 3)) * rng.uniform(0.01, 100.0, (3000, 1)), t, edges,
                        edges + rng.normal(size=edges.shape) * 1e-10, GEODESIC_MID_TRIANGLES.reshape(-1, 3)])
    assert [geodesic_section(x) for x in v] == geodesic_sections(v).tolist()


@settings(derandomize=True, max_examples=60, deadline=None)
@given(st.tuples(*[st.floats(-1e3, 1e3, allow_nan=False)] * 3).filter(lambda v: np.linalg.norm(v) > 1e-3))
def test_every_direction_lands_in_exactly_one_valid_section(v):
    s = int(geodesic_sections(np.array([v]))[0])
    assert 0 <= s < 80
    assert geodesic_section(np.array(v)) == s
    # scale invariance: a section is a direction, not a magnitude
    assert int(geodesic_sections(np.array([v]) * 7.5)[0]) == s


def test_completion_mask_bits():
    mask = completion_mask_bytes(np.array([0, 7, 8, 79, 79, -1]))
    assert len(mask) == 10
    assert mask[0] == 0b1000_0001 and mask[1] == 0b0000_0001 and mask[9] == 0b1000_0000
    assert sum(bin(b).count("1") for b in completion_mask_bytes(np.arange(80))) == 80


def test_ardupilot_convention_symmetric_model_is_exact():
    hard = np.array([12.0, -3.5, 40.0])
    soft = np.array([[1.05, 0.02, -0.03], [0.02, 0.97, 0.01], [-0.03, 0.01, 1.01]])
    ap = to_ardupilot(MagModel(hard, soft))
    assert np.allclose(ap.ofs_mgauss, [-120.0, 35.0, -400.0])      # ofs = −hard iron, in mgauss
    assert np.allclose(ap.diag, [1.05, 0.97, 1.01])
    assert np.allclose(ap.offdiag, [0.02, -0.03, 0.01])             # (12, 13, 23)
    assert ap.residual_rotation_deg < 1e-4
    raw = np.array([[300.0, -100.0, 420.0], [10.0, 20.0, -30.0]])   # µT
    # ArduPilot applies S·(raw_mG + ofs): must equal our calibrated field in mgauss
    ours = MagModel(hard, soft).apply(raw) * 10
    theirs = (raw * 10 + ap.ofs_mgauss) @ ap.matrix().T * ap.scale_factor
    assert np.allclose(ours, theirs)
    back = from_ardupilot(ap.ofs_mgauss, ap.diag, ap.offdiag, ap.scale_factor)
    assert np.allclose(back.hard_iron_ut, hard) and np.allclose(back.soft_iron, soft)


def test_ardupilot_convention_reports_rotation_it_cannot_carry():
    p = np.array([[1.02, 0.01, 0.0], [0.01, 0.98, 0.0], [0.0, 0.0, 1.0]])
    r = Rotation.from_euler("z", 3.0, degrees=True).as_matrix()
    ap = to_ardupilot(MagModel(np.zeros(3), r @ p))
    assert abs(ap.residual_rotation_deg - 3.0) < 1e-6
    assert np.allclose(ap.matrix(), p)


def test_ardupilot_scale_factor_zero_means_unset():
    m = from_ardupilot([10, 0, 0], [1, 1, 1], [0, 0, 0], 0.0)
    assert np.allclose(m.soft_iron, np.eye(3)) and np.allclose(m.hard_iron_ut, [-1, 0, 0])


def test_fixed_yaw_keeps_soft_iron_and_reproduces_the_wmm_field():
    ref = earth_field(35.7, 51.4)
    soft_true = np.array([[1.04, 0.02, 0.0], [0.02, 0.97, 0.01], [0.0, 0.01, 1.0]])
    hard_true = np.array([15.0, -7.0, 4.0])
    current = MagModel(np.array([2.0, 2.0, 2.0]), np.linalg.inv(soft_true))  # soft iron right, offsets stale
    yaw_true, roll, pitch = 123.0, math.radians(4.0), math.radians(-3.0)
    c_bn = Rotation.from_euler("ZYX", [math.radians(yaw_true), pitch, roll]).as_matrix()
    raw = soft_true @ (c_bn.T @ ref.ned_ut) + hard_true
    res = fixed_yaw_calibration(yaw_true, ref, roll, pitch, raw, current)
    assert np.array_equal(res.model.soft_iron, current.soft_iron)  # unlike ArduPilot: soft iron kept
    assert np.allclose(res.model.hard_iron_ut, hard_true, atol=1e-9)
    # heading computed with the new model equals the given true heading minus declination (magnetic)
    psi = tilt_compensated_heading_rad(res.model.apply(raw), roll, pitch)[0]
    assert abs(math.degrees(psi) - (yaw_true - math.degrees(ref.declination_rad))) < 1e-6


def test_heading_slew_bounds_rate_and_follows_motion():
    slew = HeadingSlew(max_rate_deg_s=2.0)
    dt = 0.02
    assert slew.update(0.0, math.radians(100.0)) == math.radians(100.0)  # passthrough before a transition
    slew.start_transition()
    out = []
    t = 0.0
    heading_est = math.radians(110.0)  # the new calibration moved the estimator's heading by +10°
    for _ in range(int(12.0 / dt)):
        t += dt
        out.append(math.degrees(slew.update(t, heading_est, 0.0)))
    steps = np.abs(np.diff([100.0] + out))
    assert steps.max() <= 2.0 * dt + 1e-9
    assert abs(out[int(4.0 / dt)] - 108.0) < 0.1      # 2°/s
    assert abs(out[-1] - 110.0) < 1e-9 and not slew.active   # done after min_duration_s (10 s)


def test_heading_slew_waits_for_the_estimator_to_move():
    """The estimator takes the new field a moment after the swap: the transition must not end at once."""
    slew = HeadingSlew(max_rate_deg_s=2.0, min_duration_s=10.0)
    slew.update(0.0, 0.0)
    slew.start_transition()
    dt = 0.02
    for k in range(1, 51):                       # 1 s: the estimator's heading has not moved yet
        slew.update(k * dt, 0.0)
    assert slew.active
    out = [math.degrees(slew.update(1.0 + k * dt, math.radians(30.0))) for k in range(1, 100)]
    assert max(np.abs(np.diff([0.0] + out))) <= 2.0 * dt + 1e-9   # then the 30° jump is slewed, not passed


def test_heading_slew_passes_vehicle_rotation_through():
    slew = HeadingSlew(max_rate_deg_s=1.0)
    slew.update(0.0, 0.0)
    slew.start_transition()
    rate = math.radians(20.0)  # the vehicle turns at 20°/s while the new calibration adds 5°
    dt = 0.02
    t = 0.0
    for _ in range(50):
        t += dt
        pub = slew.update(t, rate * t + math.radians(5.0), rate)
    # after 1 s: vehicle turned 20°, correction progressed by 1°
    assert abs(math.degrees(pub) - 21.0) < 1e-6


def test_max_heading_change_of_a_pure_offset():
    from ahrsd.calibration.mag.heading_change import blend_models, max_heading_change_deg

    old = MagModel(np.zeros(3), np.eye(3))
    new = MagModel(np.array([2.0, 0.0, 0.0]), np.eye(3))  # 2 µT along x on a 25 µT horizontal field
    b = np.array([25.0, 0.0, 40.0])
    d = max_heading_change_deg(old, new, b, 0.0, 0.0)
    assert abs(d - math.degrees(math.asin(2.0 / 25.0))) < 0.2   # worst case: offset across the field
    assert max_heading_change_deg(old, old, b, 0.1, -0.05) < 1e-9
    half = blend_models(old, new, 0.5)
    assert np.allclose(half.hard_iron_ut, [1.0, 0, 0]) and blend_models(old, new, 7).hard_iron_ut[0] == 2.0
