"""Coverage, tilt, condition number, undetermined parameters and refusals (calibration/mag/observability.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.spatial.transform import Rotation

from ahrsd.calibration.mag import observability as ob
from ahrsd.core import angles
from ahrsd.estimator.rotations import euler_to_dcm

G = 9.80665
FIELD_NED = np.array([28.0, 2.4, 39.9])    # µT, Tehran-like (WMM2025)


def _data(tilt_deg, n=1500, turns=2.0, seed=0, sphere=False):
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, n)
    yaw = 2 * math.pi * turns * t
    if sphere:
        roll, pitch = math.pi * np.sin(2 * math.pi * 5.3 * t), math.radians(80) * np.sin(2 * math.pi * 3.7 * t)
    else:
        a = math.radians(tilt_deg)
        roll, pitch = a * np.sin(2 * math.pi * 7 * t), a * np.sin(2 * math.pi * 5 * t + 1)
    r = Rotation.from_euler("ZYX", np.column_stack((yaw, pitch, roll)))
    mag = r.inv().apply(FIELD_NED) * [1.05, 0.95, 1.0] + [20.0, -10.0, 30.0] + rng.normal(0, 0.125, (n, 3))
    acc = r.inv().apply([0, 0, -G])
    return mag, acc, roll, pitch


def test_coverage_full_sphere_vs_level_turns():
    mag, *_ = _data(0, sphere=True, n=3000)
    assert ob.sphere_cells_hit(mag, [20.0, -10.0, 30.0]).mean() > 0.9
    mag, *_ = _data(10)
    assert ob.sphere_cells_hit(mag, [20.0, -10.0, 30.0]).mean() < 0.4


@settings(max_examples=50, deadline=None, derandomize=True)
@given(st.floats(-1.5, 1.5), st.floats(-1.4, 1.4), st.floats(-3.1, 3.1))
def test_roll_pitch_from_accel_and_levelling_match_the_dcm(roll, pitch, yaw):
    cbn = euler_to_dcm(roll, pitch, yaw)
    f_body = cbn.T @ np.array([0.0, 0.0, -G])
    r, p = angles.roll_pitch_from_accel(f_body[None, :])
    assert r[0] == pytest.approx(roll, abs=1e-9) and p[0] == pytest.approx(pitch, abs=1e-9)
    v_body = cbn.T @ FIELD_NED
    lv = ob.level_vectors(v_body[None, :], np.array([roll]), np.array([pitch]))[0]
    # levelled = yaw-only rotation of NED: same vertical, same horizontal magnitude
    assert lv[2] == pytest.approx(FIELD_NED[2], abs=1e-9)
    assert math.hypot(lv[0], lv[1]) == pytest.approx(math.hypot(*FIELD_NED[:2]), abs=1e-9)
    np.testing.assert_allclose(angles.down_in_body(np.array([roll]), np.array([pitch]))[0], cbn[2], atol=1e-12)


def test_lowpass_is_zero_phase_and_passes_constants():
    t = np.arange(0, 60, 0.1)
    x = np.column_stack((np.sin(2 * math.pi * t / 30), np.full(t.size, 3.0)))
    y = ob.lowpass(x, t, 0.2)
    np.testing.assert_allclose(y[:, 1], 3.0)
    k = np.argmax(y[100:400, 0]) + 100
    assert abs(t[k] - 7.5 - 30 * round((t[k] - 7.5) / 30)) < 0.15     # peak not delayed


def test_tilt_statistics():
    r, p = np.radians([0, 10, -5]), np.radians([2, -3, 8])
    s = ob.tilt_statistics(r, p)
    assert s["roll_max_deg"] == pytest.approx(10) and s["pitch_min_deg"] == pytest.approx(-3)
    assert 9.5 < s["tilt_max_deg"] < 10.5


def test_heading_coverage_with_and_without_reference_radius():
    mag, _, roll, pitch = _data(5, turns=1.0)
    assert ob.heading_coverage(mag, roll, pitch, horizontal_ut=28.1) > 0.95
    mag, _, roll, pitch = _data(5, turns=0.05)      # one way only (18°)
    assert ob.heading_coverage(mag, roll, pitch, horizontal_ut=28.1) < 0.2


def test_parameter_uncertainty_flags_an_unobservable_parameter():
    rng = np.random.default_rng(0)
    j = rng.normal(size=(200, 3))
    j[:, 2] = j[:, 0] * 2.0 + 1e-9 * rng.normal(size=200)      # third column ≈ a copy of the first
    u = ob.parameter_uncertainty(j, ["a", "b", "c"], {"a": 1.0, "b": 1.0, "c": 1.0})
    assert u["condition_number"] > 1e6
    assert "c" in u["undetermined"] and "b" not in u["undetermined"]
    assert u["std"]["b"] == pytest.approx(1 / math.sqrt(200), rel=0.2)


def test_support_refusals_and_acceptances():
    mag, acc, *_ = _data(10)
    ell = ob.assess_support(mag, acc, "ellipsoid")
    assert ell.refused and "vertical" in ell.refused and "backstepping" in ell.refused
    assert ob.assess_support(mag, acc, "vertical").refused is None
    mag_s, acc_s, *_ = _data(0, sphere=True, n=3000)
    assert ob.assess_support(mag_s, acc_s, "ellipsoid").refused is None
    mag2, acc2, *_ = _data(2)
    fd = ob.assess_support(mag2, acc2, "vertical-free-dip")
    assert fd.refused and "--lat/--lon" in fd.refused
    mag1, acc1, *_ = _data(5, turns=0.05)
    one = ob.assess_support(mag1, acc1, "vertical", horizontal_ut=28.1)
    assert one.refused and "full circle" in one.refused
    assert "roll and pitch" in ob.assess_support(mag, None, "vertical").refused
    assert "samples" in ob.assess_support(mag[:10], acc[:10], "vertical").refused
    still = mag[:1] + np.random.default_rng(3).normal(0, 0.125, (500, 3))      # a still sensor: noise only
    for model in ("vertical", "ellipsoid", "sphere"):
        r = ob.assess_support(still, np.repeat(acc[:1], 500, axis=0), model)
        assert r.refused and "did not turn" in r.refused
    lvl = ob.assess_support(*_data(0.2)[:2], "vertical")
    assert lvl.refused is None and lvl.undetermined and lvl.warnings
    q = lvl.as_quality()
    assert q["support_model"] == "vertical" and "tilt" in q
    with pytest.raises(ValueError):
        ob.assess_support(mag, acc, "nonsense")
