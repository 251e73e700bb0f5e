"""The rows of bench/tilt_split.py that split the uncalibrated boat's tilt between the IMU's errors and the
receiver's (docs/estimator.md "Session 42 (tiltstep)"): a perfect IMU keeps the magnetometer as simulated; the
quiet receiver draws no velocity noise but reports the same accuracy; the down velocity put back is the noisy
one, north and east stay quiet. Checked against the simulator's own figures and worked values."""

import numpy as np

from ahrsd.core.gnss import GnssFix
from ahrsd.simulation import SensorErrors
from bench.tilt_split import perfect_imu, quiet_velocity_receiver, with_down_velocity_of
from bench.vehicle_accuracy import GNSS_ERRORS


def test_a_perfect_imu_has_no_gyro_or_accelerometer_error_and_keeps_the_magnetometer():
    sensor = SensorErrors.adis16405(103)
    imu = perfect_imu(sensor)
    for vec in (imu.gyro_bias_rad_s, imu.gyro_scale, imu.gyro_bias_temp_rad_s_per_c, imu.accel_bias_m_s2,
                imu.accel_scale, imu.accel_bias_temp_m_s2_per_c):
        assert np.all(vec == 0.0)
    assert np.all(imu.gyro_misalignment_rad == 0.0) and np.all(imu.accel_misalignment_rad == 0.0)
    assert imu.gyro_noise_density_rad_s_rthz == 0.0 and imu.accel_noise_density_m_s2_rthz == 0.0
    assert imu.gyro_bias_instability_rad_s == 0.0 and imu.accel_bias_instability_m_s2 == 0.0
    # the seed's sensor had errors to remove (an ADIS16405 draw), and its magnetometer is untouched
    assert np.all(sensor.accel_bias_m_s2 != 0.0) and np.all(sensor.gyro_scale != 0.0)
    np.testing.assert_array_equal(imu.hard_iron_ut, sensor.hard_iron_ut)
    np.testing.assert_array_equal(imu.soft_iron, sensor.soft_iron)
    assert imu.mag_noise_density_ut_rthz == sensor.mag_noise_density_ut_rthz


def test_the_quiet_receiver_draws_no_velocity_noise_and_reports_the_same_accuracy():
    quiet = quiet_velocity_receiver()
    assert quiet.velocity_m_s == 0.0
    assert quiet.horizontal_m == GNSS_ERRORS["horizontal_m"] == 1.5
    assert quiet.vertical_m == GNSS_ERRORS["vertical_m"] == 2.5
    assert quiet.reported == (1.5, 2.5, 0.05)      # what the filter weights the fixes by


def _fix(t_s, v_ned):
    return GnssFix(t_s, -33.92, 18.42, 10.0, np.array(v_ned, dtype=float), 1.5, 2.5, 0.05)


def test_the_down_velocity_put_back_is_the_noisy_one_north_and_east_stay_quiet():
    quiet = [_fix(0.0, [1.0, 2.0, 0.0]), _fix(0.2, [1.1, 2.1, 0.0])]
    noisy = [_fix(0.0, [1.04, 1.97, 0.03]), _fix(0.2, [1.06, 2.12, -0.05])]
    out = with_down_velocity_of(quiet, noisy)
    np.testing.assert_array_equal(out[0].vel_ned_m_s, [1.0, 2.0, 0.03])
    np.testing.assert_array_equal(out[1].vel_ned_m_s, [1.1, 2.1, -0.05])
    assert [f.t_s for f in out] == [0.0, 0.2]
    np.testing.assert_array_equal(quiet[0].vel_ned_m_s, [1.0, 2.0, 0.0])     # the quiet fixes are not written
