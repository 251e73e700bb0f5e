"""The simulator's optional true-field anomaly (session 41, anomaly): the field the magnetometer senses is WMM's plus
a constant NED vector, while the stream's `earth_field` (what an estimator is told) stays WMM's.

Truth is computed here independently of the simulator's rotation code: scipy's Rotation of the truth attitude
(body → NED) applied inverse to the NED vector, C_n^b v.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ahrsd.simulation import SensorErrors, Site, open_stream
from bench.heading_timeline import anomaly_ned_ut
from bench.vehicle_accuracy import honesty_iron, simulate_vehicle

RIO = Site.parse("-22.91,-43.17")
ANOMALY_NED_UT = np.array([0.3, 1.0, -0.2])      # north, east, down; a local anomaly of ~1 µT
SAMPLES = 2000                                    # ~2.4 s of the tumble at 819.2 Hz: every axis turns


def _body(q_wxyz: np.ndarray, ned: np.ndarray) -> np.ndarray:
    return Rotation.from_quat(q_wxyz[:, [1, 2, 3, 0]]).inv().apply(ned)


def test_the_anomaly_reaches_the_magnetometer_rotated_into_the_body_frame():
    plain = open_stream("tumble", seed=5, errors="ideal", site=RIO, vehicle_iron=None)
    anomalous = open_stream("tumble", seed=5, errors="ideal", site=RIO, vehicle_iron=None,
                            field_anomaly_ned_ut=ANOMALY_NED_UT)
    a, b = plain.next_block(SAMPLES), anomalous.next_block(SAMPLES)
    np.testing.assert_array_equal(a.truth_q_wxyz, b.truth_q_wxyz)
    wmm_ned_ut = plain.earth_field.ned_ut
    # the ideal sensor reads the true field: WMM's alone, then WMM's plus the anomaly, each in the body frame
    np.testing.assert_allclose(a.mag_ut, _body(a.truth_q_wxyz, wmm_ned_ut), atol=1e-9)
    np.testing.assert_allclose(b.mag_ut, _body(b.truth_q_wxyz, wmm_ned_ut + ANOMALY_NED_UT), atol=1e-9)
    np.testing.assert_allclose(b.mag_ut - a.mag_ut, _body(b.truth_q_wxyz, ANOMALY_NED_UT), atol=1e-9)
    assert np.ptp(b.mag_ut - a.mag_ut, axis=0).max() > 1.0       # the tumble turned the anomaly in the body
    # the estimator's field (and so its declination) is WMM's, not the true one
    assert anomalous.earth_field == plain.earth_field


def test_no_anomaly_is_the_stream_of_before_bit_for_bit():
    before = open_stream("boat", seed=7, site=RIO).next_block(500)
    none = open_stream("boat", seed=7, site=RIO, field_anomaly_ned_ut=None).next_block(500)
    for name in ("mag_ut", "gyro_rad_s", "accel_m_s2", "truth_mag_ut"):
        assert getattr(before, name).tobytes() == getattr(none, name).tobytes()


def test_the_bench_flag_is_east_and_reaches_the_raw_magnetometer_through_the_sensor_s_iron():
    assert anomaly_ned_ut(0.0) is None
    assert anomaly_ned_ut(1.0) == (0.0, 1.0, 0.0)
    plain = simulate_vehicle("boat", 2.0, 11, "-22.91,-43.17", mag="uncalibrated", iron="held-out")
    east = simulate_vehicle("boat", 2.0, 11, "-22.91,-43.17", mag="uncalibrated", iron="held-out",
                            field_anomaly_ned_ut=anomaly_ned_ut(1.0))
    assert east.declination_rad == plain.declination_rad
    # the raw reading is soft iron · true field + hard iron + noise (the same draws): the difference is the
    # soft iron times the anomaly in the body frame
    soft = SensorErrors.adis16405(11).with_vehicle_iron(honesty_iron("held-out")).soft_iron
    diff = east.mag_ut - plain.mag_ut
    np.testing.assert_allclose(diff, _body(east.truth_q_wxyz, np.array([0.0, 1.0, 0.0])) @ soft.T, atol=1e-9)
    assert 0.5 < np.linalg.norm(diff, axis=1).mean() < 2.0                   # ~1 µT through a near-unit soft iron
