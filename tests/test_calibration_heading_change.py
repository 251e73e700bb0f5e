"""A magnetometer calibration change widens what the estimator learned from the old calibration's heading (#28
item 3, "σ must cover the error"): how far the new calibration moves the heading (daemon.calibration_heading_change,
checked against a field rotated by scipy), and the covariance it raises (estimator.mag_heading
widen_after_calibration_change: worked numbers; mekf and ins through relearn_field_reference)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.calibration.models import Calibration, MagModel
from ahrsd.core.sample import ImuSample, SampleFlags
from ahrsd.core.sample_block import SampleBlock
from ahrsd.daemon.calibration_heading_change import calibration_heading_change_rad
from ahrsd.daemon.calibration_swap import CalibrationSwap
from ahrsd.daemon.pipeline import Pipeline
from ahrsd.estimator import make_estimator
from ahrsd.estimator.mag_heading import widen_after_calibration_change
from ahrsd.core.sample import make_sample
from ins_truth import gnss_fixes, run_ins, simulated_run

FIELD_NED_UT = np.array([20.0, -3.0, 45.0])    # a magnetic field with a declination (the heading is magnetic)


def _body_field(roll_deg, pitch_deg, yaw_deg):
    """The Earth field in the body frame of a vehicle at (roll, pitch, yaw) from true north, by scipy (ZYX)."""
    c_nb = Rotation.from_euler("ZYX", [yaw_deg, pitch_deg, roll_deg], degrees=True)   # body → NED
    return c_nb.inv().apply(FIELD_NED_UT)


@pytest.mark.parametrize("roll_deg,pitch_deg,yaw_deg,est_yaw_deg", [(0.0, 0.0, 30.0, 80.0),
                                                                    (12.0, -7.0, -150.0, 170.0)])
def test_the_heading_change_is_the_new_calibrations_heading_minus_the_estimators(roll_deg, pitch_deg, yaw_deg,
                                                                                 est_yaw_deg):
    hard_iron = np.array([25.0, -30.0, 12.0])
    soft = np.array([[1.08, 0.05, 0.0], [0.05, 0.95, 0.02], [0.0, 0.02, 1.01]])
    raw = np.linalg.solve(soft, _body_field(roll_deg, pitch_deg, yaw_deg)) + hard_iron   # m = S (raw − h)
    old = Calibration.identity()                                     # the iron not calibrated
    new = Calibration.identity().with_sensor("mag", MagModel(hard_iron, soft))
    magnetic_heading = yaw_deg - math.degrees(math.atan2(FIELD_NED_UT[1], FIELD_NED_UT[0]))
    expected = (magnetic_heading - est_yaw_deg + 180.0) % 360.0 - 180.0
    got = calibration_heading_change_rad(old, new, raw, None, math.radians(roll_deg), math.radians(pitch_deg),
                                         math.radians(est_yaw_deg))
    assert math.degrees(got) == pytest.approx(expected, abs=1e-9)
    # a mounting: the sample is in the sensor frame, the attitude the body's
    mount = Rotation.from_euler("z", 90.0, degrees=True).as_matrix()           # sensor → body
    raw_sensor = np.linalg.solve(soft, mount.T @ _body_field(roll_deg, pitch_deg, yaw_deg)) + hard_iron
    got = calibration_heading_change_rad(old, new, raw_sensor, mount, math.radians(roll_deg),
                                         math.radians(pitch_deg), math.radians(est_yaw_deg))
    assert math.degrees(got) == pytest.approx(expected, abs=1e-9)
    # the raw field goes through the new calibration alone, whatever the old one was
    other = Calibration.identity().with_sensor("mag", MagModel(np.array([3.0, 1.0, -2.0]), np.eye(3) * 1.1))
    got = calibration_heading_change_rad(other, new, raw, None, math.radians(roll_deg),
                                         math.radians(pitch_deg), math.radians(est_yaw_deg))
    assert math.degrees(got) == pytest.approx(expected, abs=1e-9)


class _Still:
    """An estimator holding one attitude (roll, pitch, yaw from magnetic north), telling what it is asked to widen
    its heading by."""

    def __init__(self, roll_deg, pitch_deg, yaw_deg):
        self.estimate = SimpleNamespace(roll_rad=math.radians(roll_deg), pitch_rad=math.radians(pitch_deg),
                                        yaw_rad=math.radians(yaw_deg))
        self.widened_by = []

    def update(self, sample):
        return self.estimate

    def relearn_field_reference(self, heading_change_rad=math.nan):
        self.widened_by.append(heading_change_rad)


@pytest.mark.parametrize("mount_deg", [None, 90.0])
@pytest.mark.parametrize("path", ["sample", "block"])
def test_a_calibration_swap_widens_by_the_new_calibrations_heading_of_the_raw_field(tmp_path, mount_deg, path):
    """In the daemon, with another calibration in force (and with or without a mounting), the change is taken on the
    field as the sensor gave it: the pipeline keeps the raw sample, the new calibration alone makes the field.
    The same when the sample is the last row of a block from the reader process (Pipeline.process_block)."""
    hard_iron = np.array([25.0, -30.0, 12.0])
    soft = np.array([[1.08, 0.05, 0.0], [0.05, 0.95, 0.02], [0.0, 0.02, 1.01]])
    mount = None if mount_deg is None else Rotation.from_euler("z", mount_deg, degrees=True).as_matrix()
    body = _body_field(12.0, -7.0, -150.0)
    raw = np.linalg.solve(soft, body if mount is None else mount.T @ body) + hard_iron
    in_force = Calibration.identity().with_sensor("mag", MagModel(np.array([3.0, 1.0, -2.0]), np.eye(3) * 1.1))
    new = Calibration.identity().with_sensor("mag", MagModel(hard_iron, soft))
    est = _Still(12.0, -7.0, 170.0)
    pipeline = Pipeline(est, in_force, mount)
    if path == "sample":
        pipeline.process(ImuSample(0.0, np.zeros(3), np.array([0.0, 0.0, -9.81]), raw, 25.0, 5.0,
                                   SampleFlags.NEW_DATA, 0, 0))
    else:       # an earlier row with another field, then the one the change is taken on
        vectors = np.array([[0.0, 0.0, 0.0, 0.0, 0.0, -9.81, *(raw + 7.0)], [0.0, 0.0, 0.0, 0.0, 0.0, -9.81, *raw]])
        flags = int(SampleFlags.NEW_DATA)
        for _ in pipeline.process_block(SampleBlock([0.0, 0.001], vectors, [25.0] * 2, [5.0] * 2, [flags] * 2,
                                                    [0, 0], [0, 1])):
            pass
    heading = SimpleNamespace(signal=lambda: None)
    CalibrationSwap(pipeline, tmp_path, heading, reset_counter_on_calibration=True).apply(new, save=False)
    magnetic_heading = -150.0 - math.degrees(math.atan2(FIELD_NED_UT[1], FIELD_NED_UT[0]))
    expected = (magnetic_heading - 170.0 + 180.0) % 360.0 - 180.0
    assert len(est.widened_by) == 1 and math.degrees(est.widened_by[0]) == pytest.approx(expected, abs=1e-9)


def test_no_heading_change_without_a_new_magnetometer_model():
    cal = Calibration.identity()
    assert calibration_heading_change_rad(cal, cal, np.array([20.0, 0.0, 40.0]), None, 0.0, 0.0, 1.0) == 0.0
    new = Calibration.identity().with_sensor("mag", MagModel(np.ones(3), np.eye(3)))
    assert math.isnan(calibration_heading_change_rad(cal, new, None, None, 0.0, 0.0, 1.0))


def _covariance():
    a = np.random.default_rng(5).normal(size=(6, 6)) * 1e-3
    return a @ a.T + np.diag([1e-4, 1e-4, 4e-4, 1e-6, 1e-6, 1e-6])


def test_the_widened_covariance_worked_numbers():
    bias_sigma = math.radians(0.5)
    P0 = _covariance()
    # level: down is the body z axis; a 40° change
    P = P0.copy()
    widen_after_calibration_change(P, 2, 3, np.array([0.0, 0.0, 1.0]), math.radians(40.0), bias_sigma)
    assert P[2, 2] == pytest.approx(math.radians(40.0) ** 2, rel=1e-12)
    assert P[5, 5] == pytest.approx(bias_sigma ** 2, rel=1e-12)
    changed = np.zeros((6, 6), bool)
    changed[2, 2] = changed[5, 5] = True
    np.testing.assert_array_equal(P[~changed], P0[~changed])        # the cross-covariances are kept
    assert np.linalg.eigvalsh(P).min() > 0.0
    # tilted: the variance along the body's down vector is raised, only along it
    u = np.array([0.3, -0.2, math.sqrt(1 - 0.13)])
    P = P0.copy()
    widen_after_calibration_change(P, 2, 3, u, math.radians(-5.0), bias_sigma)
    assert u @ P[3:, 3:] @ u == pytest.approx(bias_sigma ** 2, rel=1e-12)
    w = np.cross(u, [1.0, 0.0, 0.0])
    assert w @ P[3:, 3:] @ w == pytest.approx(w @ P0[3:, 3:] @ w, rel=1e-12)
    # a variance already larger is kept; no change (0) or an unknown one (NaN) changes nothing
    P = P0.copy()
    widen_after_calibration_change(P, 2, 3, u, math.radians(-5.0), 1e-6)
    np.testing.assert_array_equal(P[3:, 3:], P0[3:, 3:])
    # a change within the heading's 3σ (0.02 rad here) taught the bias nothing wrong: only the heading is raised
    P = P0.copy()
    change = 2.5 * math.sqrt(P0[2, 2])
    widen_after_calibration_change(P, 2, 3, u, change, bias_sigma)
    assert P[2, 2] == pytest.approx(change ** 2, rel=1e-12)
    np.testing.assert_array_equal(P[3:, 3:], P0[3:, 3:])
    for change in (0.0, math.nan):
        P = P0.copy()
        widen_after_calibration_change(P, 2, 3, u, change, bias_sigma)
        np.testing.assert_array_equal(P, P0)


@pytest.mark.parametrize("name,bias", [("mekf", 3), ("ins", 9)])
def test_relearn_field_reference_widens_the_estimators_heading_and_vertical_bias(name, bias):
    est = make_estimator(name)
    g = np.array([0.0, 0.0, -9.81])
    for k in range(400):
        est.update(make_sample(k / 100.0, np.zeros(3), g, [20.0, 0.0, 45.0]))
    before = est.covariance
    assert before[2, 2] < math.radians(30.0) ** 2
    est.relearn_field_reference(math.radians(60.0))
    after = est.covariance
    assert after[2, 2] == pytest.approx(math.radians(60.0) ** 2, rel=1e-12)
    assert after[bias + 2, bias + 2] == pytest.approx(math.radians(0.5) ** 2, rel=1e-6)   # level: down = body z
    est.relearn_field_reference()                   # unknown: nothing more
    np.testing.assert_array_equal(est.covariance, after)


def test_gnss_aided_ins_leaves_its_heading_to_the_gnss_checks():
    """Aided, ins's heading is not the old calibration's alone (its checks weigh the new one against the GNSS
    yaw): relearn_field_reference widens nothing then (on the level turns, widening moved the filter's heading to
    the new calibration's at once, which the checks then rejected against an unconverged GNSS yaw)."""
    run = simulated_run("coordinated-turn", 20.0)
    est = make_estimator("ins")
    run_ins(est, run, gnss_fixes(run.truth))
    before = est.covariance
    est.relearn_field_reference(math.radians(60.0))
    np.testing.assert_array_equal(est.covariance, before)
