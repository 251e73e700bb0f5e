"""Sensor error models and the Calibration bundle (calibration/models.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ahrsd.calibration.models import (
    SCHEMA_VERSION,
    AccelModel,
    Calibration,
    GyroModel,
    InvalidCalibrationError,
    MagModel,
    misalignment_matrix,
)
from ahrsd.core.sample import SampleFlags, make_sample

RNG = np.random.default_rng(11)


def _cal():
    return Calibration(
        GyroModel([0.01, -0.02, 0.005], np.eye(3) + RNG.normal(0, 0.01, (3, 3))),
        AccelModel([0.1, -0.05, 0.2], np.eye(3) + RNG.normal(0, 0.01, (3, 3)), [1e-4, -2e-4, 0.0]),
        MagModel([20.0, -30.0, 10.0], np.eye(3) + RNG.normal(0, 0.05, (3, 3))),
        {"sensor_id": "ADIS16405-test", "mag": {"method": "ellipsoid", "residual_rms_ut": 0.1}},
    )


def test_apply_is_matrix_times_raw_minus_bias_for_every_sensor():
    cal = _cal()
    s = make_sample(1.5, [0.3, -0.2, 0.1], [0.5, 0.2, -9.7], [25.0, 3.0, 40.0], temp_c=31.0, supply_v=5.01,
                    flags=SampleFlags.NEW_DATA, diag_stat=0, counter=42)
    out = cal.apply(s)
    np.testing.assert_allclose(out.gyro_rad_s, cal.gyro.matrix @ (s.gyro_rad_s - cal.gyro.bias_rad_s), rtol=1e-14)
    a = s.accel_m_s2
    np.testing.assert_allclose(out.accel_m_s2, cal.accel.matrix @ (a - cal.accel.bias_m_s2 - cal.accel.quadratic * a * a),
                               rtol=1e-13)
    np.testing.assert_allclose(out.mag_ut, cal.mag.soft_iron @ (s.mag_ut - cal.mag.hard_iron_ut), rtol=1e-13)
    # Everything else passes through untouched.
    assert (out.t_s, out.temp_c, out.supply_v, out.flags, out.counter) == (1.5, 31.0, 5.01, SampleFlags.NEW_DATA, 42)


def test_apply_matches_vectorised_apply_arrays():
    cal = _cal()
    g, a, m = RNG.normal(size=(3, 50, 3))
    gb, ab, mb = cal.apply_arrays(g, a, m)
    for k in range(50):
        out = cal.apply(make_sample(0.0, g[k], a[k], m[k]))
        np.testing.assert_allclose(out.gyro_rad_s, gb[k], rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(out.accel_m_s2, ab[k], rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(out.mag_ut, mb[k], rtol=1e-12, atol=1e-15)


def test_identity_returns_the_sample_unchanged():
    s = make_sample(0.0, [1, 2, 3], [4, 5, 6], [7, 8, 9])
    cal = Calibration.identity()
    assert cal.is_identity
    assert cal.apply(s) is s
    assert not _cal().is_identity


def test_to_dict_from_dict_round_trip_exact():
    cal = _cal()
    d = cal.to_dict()
    assert d["schema_version"] == SCHEMA_VERSION
    assert Calibration.from_dict(d) == cal


def test_with_sensor_keeps_the_other_sensors_and_sets_metadata():
    cal = _cal()
    new_mag = MagModel([1.0, 2.0, 3.0], np.eye(3) * 1.1)
    out = cal.with_sensor("mag", new_mag, method="two-step", residual_rms_ut=0.3)
    assert out.mag == new_mag and out.gyro == cal.gyro and out.accel == cal.accel
    assert out.metadata["mag"]["method"] == "two-step" and "date" in out.metadata["mag"]
    assert out.metadata["sensor_id"] == "ADIS16405-test"
    with pytest.raises(ValueError, match="unknown sensor"):
        cal.with_sensor("baro", new_mag)


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda d: d.pop("gyro"), "missing key 'gyro'"),
        (lambda d: d["mag"].pop("soft_iron"), "missing key 'soft_iron'"),
        (lambda d: d["accel"].__setitem__("bias_m_s2", [1.0, 2.0]), "expected 3 numbers"),
        (lambda d: d["gyro"].__setitem__("matrix", [[1, 0], [0, 1]]), "3×3"),
        (lambda d: d["mag"].__setitem__("hard_iron_ut", [1.0, float("nan"), 0.0]), "non-finite"),
        (lambda d: d["mag"].__setitem__("soft_iron", [[1, 0, 0], [0, 1, 0], [0, 0, 0]]), "singular"),
        (lambda d: d["gyro"].__setitem__("bias_rad_s", ["a", "b", "c"]), "gyro.bias_rad_s"),
        (lambda d: d.__setitem__("schema_version", 99), "schema_version 99"),
        (lambda d: d.__setitem__("metadata", [1, 2]), "metadata"),
    ],
)
def test_from_dict_rejects_bad_input_with_a_reason(mutate, message):
    d = _cal().to_dict()
    mutate(d)
    with pytest.raises(InvalidCalibrationError, match=message):
        Calibration.from_dict(d)


def test_metadata_is_made_json_safe():
    cal = Calibration(metadata={"residual": np.float64(0.5), "arr": np.arange(3), "bad": float("nan")})
    assert cal.metadata["residual"] == 0.5 and cal.metadata["arr"] == [0, 1, 2] and cal.metadata["bad"] is None


def test_models_are_read_only():
    m = MagModel([1.0, 2.0, 3.0], np.eye(3))
    with pytest.raises(ValueError):
        m.hard_iron_ut[0] = 5.0


# ---------------------------------------------------------------------------------------------- thesis form

ANGLE = st.floats(-0.05, 0.05)


@settings(derandomize=True, max_examples=60, deadline=None)
@given(
    st.lists(st.floats(-50, 50), min_size=3, max_size=3),
    st.lists(st.floats(0.7, 1.3), min_size=3, max_size=3),
    ANGLE, ANGLE, ANGLE,
    st.lists(st.floats(-0.3, 0.3), min_size=3, max_size=3),
)
def test_thesis_form_round_trips_through_soft_iron(b, k, a_yz, a_zy, a_zx, rotvec):
    """from_thesis(b, k, α, C) = C·T·K⁻¹ and to_thesis takes it apart again (QR)."""
    from scipy.spatial.transform import Rotation

    c = Rotation.from_rotvec(rotvec).as_matrix()
    alpha = {"yz": a_yz, "zy": a_zy, "zx": a_zx}
    model = MagModel.from_thesis(b, k, alpha, c)
    t = misalignment_matrix(alpha)
    np.testing.assert_allclose(model.soft_iron, c @ t @ np.diag(1 / np.array(k)), atol=1e-12)
    back = model.to_thesis()
    np.testing.assert_allclose(back.bias_ut, b, atol=1e-12)
    np.testing.assert_allclose(back.scale, k, rtol=1e-10)
    for key in alpha:
        assert back.alpha[key] == pytest.approx(alpha[key], abs=1e-10)
    np.testing.assert_allclose(back.alignment, c, atol=1e-10)


def test_thesis_measurement_model_is_inverted():
    """B = b + K·T⁻¹·H (the thesis's measurement model) → soft_iron·(B − b) = H."""
    b = np.array([7.57678, -0.502, -2.839])
    k = np.array([0.91, 0.9069, 0.9334])
    alpha = {"xy": 0.0055, "xz": 0.0052, "yx": -0.0555, "yz": -0.0202, "zx": 0.0022, "zy": -0.0002}
    h = np.array([20.0, -5.0, 41.0])
    raw = b + np.diag(k) @ np.linalg.solve(misalignment_matrix(alpha), h)
    np.testing.assert_allclose(MagModel.from_thesis(b, k, alpha).apply(raw), h, atol=1e-12)


def test_from_thesis_rejects_non_positive_scale():
    with pytest.raises(InvalidCalibrationError, match="positive"):
        MagModel.from_thesis([0, 0, 0], [1.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="unknown misalignment"):
        misalignment_matrix({"xx": 0.1})


def test_apply_handles_nan_inputs_without_raising():
    out = _cal().apply(make_sample(0.0, [math.nan] * 3, [0, 0, -9.8], [math.nan] * 3))
    assert np.all(np.isnan(out.gyro_rad_s)) and np.all(np.isfinite(out.accel_m_s2))
