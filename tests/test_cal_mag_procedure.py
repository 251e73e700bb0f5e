"""The `ahrsd calibrate mag` procedure as one call (calibration.mag.procedure.calibrate_mag): the alignment step
folded into the three-step fit, the swing table folded in, and a step that cannot be done named in the error.
Truth: the simulator's sensor errors (the thesis's worked example), not the code under test."""

from __future__ import annotations

import contextlib
import math

import numpy as np
import pytest

from ahrsd.calibration.mag import procedure
from ahrsd.calibration.mag.fit_types import MagFitInput
from ahrsd.calibration.models import MagModel
from ahrsd.simulation import DEFAULT_SITE, SensorErrors, simulate

RATE_HZ = 20.0
REF = DEFAULT_SITE.earth_field()


@pytest.fixture(scope="module")
def thesis_sensor():
    b = np.array([75.7678, -5.02, -28.39]) * 0.1            # mG → µT
    k = np.array([0.91, 0.9069, 0.9334])
    alpha = {"xy": 0.0055, "xz": 0.0052, "yx": -0.0555, "yz": -0.0202, "zx": 0.0022, "zy": -0.0002}
    truth = MagModel.from_thesis(b, k, alpha)
    errs = SensorErrors.adis16405(seed=2).replace(hard_iron_ut=b, soft_iron=np.linalg.inv(truth.soft_iron))
    tumble = simulate("tumble", 150.0, rate_hz=RATE_HZ, seed=1, errors=errs, vehicle_iron=None)
    table = simulate("rate-table", 420, rate_hz=RATE_HZ, seed=3, errors=errs.replace(
        accel_bias_m_s2=np.zeros(3), accel_misalignment_rad=np.zeros((3, 3))))
    data = MagFitInput(tumble.t_s, tumble.mag_ut, tumble.accel_m_s2, tumble.gyro_rad_s)
    alignment = procedure.AlignmentRecording(table.gyro_rad_s, table.accel_m_s2, table.mag_ut, RATE_HZ)
    return truth, data, alignment


def test_three_step_with_the_alignment_step_recovers_the_rotation(thesis_sensor):
    truth, data, alignment = thesis_sensor
    steps = []

    def step(description):
        steps.append(description)
        return contextlib.nullcontext()

    out = procedure.calibrate_mag("three-step", data, REF, alignment=alignment, step=step)
    assert out.result.ok, out.result.refused
    # the rotation part of T·K⁻¹ is only there when the alignment was folded into the final fit
    np.testing.assert_allclose(out.result.model.soft_iron, truth.soft_iron, atol=1e-3)
    assert out.notes and out.notes[0].startswith("alignment from 6 levelled turns")
    assert steps == [f"fitting (three-step) {len(data)} samples", "fitting the alignment",
                     f"fitting (three-step) {len(data)} samples"]
    plain = procedure.calibrate_mag("three-step", data, REF)
    assert plain.notes == ()
    assert np.max(np.abs(plain.result.model.soft_iron - truth.soft_iron)) > 1e-2


def test_a_swing_table_folds_its_constant_into_the_heading(thesis_sensor):
    _, data, _ = thesis_sensor
    reference = np.arange(0.0, 360.0, 45.0)
    table = procedure.SwingTable(reference, (reference - 2.0) % 360.0, "swing.csv")   # compass reads 2° low
    plain = procedure.calibrate_mag("ellipsoid", data, REF).result
    swung = procedure.calibrate_mag("ellipsoid", data, REF, swing_table=table).result
    assert swung.quality["heading_reference"]["folded_offset_deg"] == pytest.approx(2.0, abs=1e-9)
    # a heading offset is a rotation about the body z axis applied after the fit: the magnitude is unchanged
    v = np.array([20.0, 5.0, 40.0])
    a, b = plain.model.apply(v[None])[0], swung.model.apply(v[None])[0]
    assert np.linalg.norm(a) == pytest.approx(np.linalg.norm(b), rel=1e-12)
    turn = math.degrees(math.atan2(a[0] * b[1] - a[1] * b[0], a[0] * b[0] + a[1] * b[1]))
    assert abs(turn) == pytest.approx(2.0, abs=1e-6)


def test_a_step_that_cannot_be_done_is_named(thesis_sensor):
    _, data, alignment = thesis_sensor
    with pytest.raises(procedure.MagCalibrationError) as err:
        procedure.calibrate_mag("two-step", data, REF, alignment=alignment)
    assert err.value.step == "alignment"
    with pytest.raises(procedure.MagCalibrationError) as err:
        procedure.calibrate_mag("ellipsoid", data, REF, gnss=procedure.GnssLevelling([]))
    assert err.value.step == "gnss"
    flat = procedure.SwingTable(np.array([np.nan]), np.array([np.nan]), "one.csv")   # no usable pair
    with pytest.raises(procedure.MagCalibrationError) as err:
        procedure.calibrate_mag("ellipsoid", data, REF, swing_table=flat)
    assert err.value.step == "swing-table" and "one.csv" in str(err.value)
