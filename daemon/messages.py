"""Builders for the MAVLink messages ahrsd sends: pure functions from estimates/samples to message objects.

Units follow common.xml: angles rad, rates rad/s, HIGHRES_IMU magnetic field in gauss
(1 gauss = 100 µT), SCALED_IMU in mG / mrad/s / mgauss int16. Attitudes are published relative to TRUE north
(both ArduPilot's and PX4's EKFs work in true-north NED): the estimator reports a magnetic yaw,
the daemon adds the declination.
"""

from __future__ import annotations

import math

import numpy as np

from ahrsd.core.angles import STANDARD_GRAVITY_M_S2, wrap_pi_float
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.statustext_ascii import statustext_ascii

UT_PER_GAUSS = 100.0               # 1 gauss = 100 µT
HIGHRES_IMU_FIELDS_ADIS = 0x11FF   # acc, gyro, mag xyz + temperature (common.xml HIGHRES_IMU_UPDATED_FLAGS)
INT16_MAX = 32767
# VISION_POSITION_ESTIMATE: we have no position; x=y=z=0 with a large variance says "do not use". Both
# EKFs are configured not to fuse it (ArduPilot EK3_SRC1_POSXY=GPS, PX4 EKF2_EV_CTRL=8), and ArduPilot drops
# a sample with NaN position (AP_NavEKF3 writeExtNavData), so the covariance is kept fully finite.
VPE_POSITION_VARIANCE_M2 = 1.0e4   # (100 m)², ArduPilot clamps posErr to 100 m
UPPER_TRIANGLE_DIAG = (0, 6, 11, 15, 18, 20)  # indices of x,y,z,roll,pitch,yaw variances in the 21-vector
STATUSTEXT_LEN = 50                # STATUSTEXT.text char[50]
STATUSTEXT_MAX_CHUNKS = 256        # STATUSTEXT.chunk_seq uint8

# MAV_SYS_STATUS_SENSOR bits (common.xml)
SENSOR_GYRO = mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
SENSOR_ACCEL = mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
SENSOR_MAG = mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG
SENSOR_AHRS = mavlink.MAV_SYS_STATUS_AHRS


def true_quaternion(q_wxyz: np.ndarray, declination_rad: float) -> tuple[float, float, float, float]:
    """Rotate a body→magnetic-NED quaternion into true-north NED: q_true = q_z(declination) ⊗ q_mag."""
    c, s = math.cos(0.5 * declination_rad), math.sin(0.5 * declination_rad)
    w, x, y, z = (float(v) for v in q_wxyz)
    return (c * w - s * z, c * x - s * y, c * y + s * x, c * z + s * w)


def heartbeat(mav_type: int, system_status: int):
    return mavlink.MAVLink_heartbeat_message(mav_type, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, system_status, 3)


def attitude(est, time_boot_ms: int, yaw_true_rad: float):
    p, q, r = (float(v) for v in est.rate_body_rad_s)
    return mavlink.MAVLink_attitude_message(time_boot_ms, est.roll_rad, est.pitch_rad, wrap_pi_float(float(yaw_true_rad)), p, q, r)


def attitude_quaternion(est, time_boot_ms: int, declination_rad: float):
    w, x, y, z = true_quaternion(est.q_wxyz, declination_rad)
    p, q, r = (float(v) for v in est.rate_body_rad_s)
    return mavlink.MAVLink_attitude_quaternion_message(time_boot_ms, w, x, y, z, p, q, r, [0.0, 0.0, 0.0, 0.0])


def vision_position_estimate(est, usec: int, yaw_true_rad: float, reset_counter: int,
                             yaw_sigma_rad: float | None = None):
    """Zero position, true-north attitude, covariance with the filter's roll/pitch variances and the yaw's
    (`yaw_sigma_rad`, default the filter's: a yaw that is not the filter's carries its own)."""
    cov = [0.0] * 21
    for i in UPPER_TRIANGLE_DIAG[:3]:
        cov[i] = VPE_POSITION_VARIANCE_M2
    sr, sp, sy = (float(v) for v in est.sigma_rpy_rad)
    if yaw_sigma_rad is not None:
        sy = float(yaw_sigma_rad)
    cov[15], cov[18], cov[20] = sr * sr, sp * sp, sy * sy
    if not all(math.isfinite(c) for c in cov[15:]):
        cov[15] = cov[18] = cov[20] = (math.pi / 2) ** 2   # finite "very uncertain" (ArduPilot clamps at 1.5 rad)
    return mavlink.MAVLink_vision_position_estimate_message(
        usec, 0.0, 0.0, 0.0, est.roll_rad, est.pitch_rad, wrap_pi_float(float(yaw_true_rad)), cov, reset_counter & 0xFF)


def _clip(value: float, lo: int, hi: int) -> int:
    return 0 if not math.isfinite(value) else max(lo, min(hi, int(round(value))))


def local_position_ned(time_boot_ms: int, pos_ned_m, vel_ned_m_s):
    """Position (m) from the local origin and velocity (m/s), NED. A NaN down velocity is sent as 0."""
    x, y, z = (float(v) for v in pos_ned_m)
    vx, vy, vz = (float(v) if math.isfinite(v) else 0.0 for v in vel_ned_m_s)
    return mavlink.MAVLink_local_position_ned_message(time_boot_ms, x, y, z, vx, vy, vz)


def global_position_int(time_boot_ms: int, lat_deg: float, lon_deg: float, alt_m: float, relative_alt_m: float,
                        vel_ned_m_s, heading_true_rad: float):
    """lat/lon degE7, alt/relative_alt mm, velocity cm/s NED (int16), heading cdeg [0, 36000) (common.xml #33)."""
    vx, vy, vz = (_clip(float(v) * 100.0, -INT16_MAX, INT16_MAX) for v in vel_ned_m_s)
    hdg = int(round(math.degrees(heading_true_rad) * 100.0)) % 36000 if math.isfinite(heading_true_rad) else 0xFFFF
    return mavlink.MAVLink_global_position_int_message(
        time_boot_ms, _clip(lat_deg * 1e7, -900_000_000, 900_000_000), _clip(lon_deg * 1e7, -1_800_000_000, 1_800_000_000),
        _clip(alt_m * 1000.0, -2**31, 2**31 - 1), _clip(relative_alt_m * 1000.0, -2**31, 2**31 - 1), vx, vy, vz, hdg)


def highres_imu(sample, usec: int, imu_id: int = 0):
    a, g, m = sample.accel_m_s2, sample.gyro_rad_s, sample.mag_ut / UT_PER_GAUSS
    temp = float(sample.temp_c)
    fields = HIGHRES_IMU_FIELDS_ADIS if math.isfinite(temp) else HIGHRES_IMU_FIELDS_ADIS & ~0x1000
    return mavlink.MAVLink_highres_imu_message(
        usec, float(a[0]), float(a[1]), float(a[2]), float(g[0]), float(g[1]), float(g[2]),
        float(m[0]), float(m[1]), float(m[2]), 0.0, 0.0, 0.0, temp if math.isfinite(temp) else 0.0, fields, imu_id)


def _i16(value: float) -> int:
    if not math.isfinite(value):
        return 0
    return max(-INT16_MAX, min(INT16_MAX, int(round(value))))


def scaled_imu(sample, time_boot_ms: int):
    a = sample.accel_m_s2 * (1000.0 / STANDARD_GRAVITY_M_S2)      # mG
    g = sample.gyro_rad_s * 1000.0             # mrad/s
    m = sample.mag_ut * (1000.0 / UT_PER_GAUSS)  # mgauss
    t = float(sample.temp_c)
    temp_cdeg = 0 if not math.isfinite(t) else (_i16(t * 100.0) or 1)   # "0: no temperature; at 0C send 1"
    return mavlink.MAVLink_scaled_imu_message(
        time_boot_ms, _i16(a[0]), _i16(a[1]), _i16(a[2]), _i16(g[0]), _i16(g[1]), _i16(g[2]),
        _i16(m[0]), _i16(m[1]), _i16(m[2]), temp_cdeg)


def sys_status(present: int, enabled: int, health: int, load_permille: int, errors_comm: int,
               errors_count: tuple[int, int, int, int] = (0, 0, 0, 0), drop_rate_comm: int = 0):
    u16 = lambda v: max(0, min(0xFFFF, int(v)))  # noqa: E731
    return mavlink.MAVLink_sys_status_message(
        present, enabled, health, u16(load_permille), 0xFFFF, -1, -1, u16(drop_rate_comm), u16(errors_comm),
        *(u16(v) for v in errors_count), 0, 0, 0)


def statustext_chunks(severity: int, text: str, chunk_id: int) -> list:
    """The STATUSTEXT messages of `text` (ASCII, daemon.statustext_ascii): one message with id 0 when it fits
    STATUSTEXT_LEN bytes, else MAVLink 2 chunks sharing `chunk_id` (1..65535) with chunk_seq 0, 1, ... (common.xml
    STATUSTEXT: "a value of zero indicates this is the only chunk"; "any null character in the text field is taken
    to mean this was the last chunk"). A text of a whole number of chunks gets an empty last chunk (all NUL), so
    the receiver still sees where it ends."""
    data = statustext_ascii(text)[:STATUSTEXT_MAX_CHUNKS * STATUSTEXT_LEN - 1]   # chunk_seq is a uint8
    if len(data) <= STATUSTEXT_LEN:
        return [mavlink.MAVLink_statustext_message(severity, data, 0, 0)]
    parts = [data[i:i + STATUSTEXT_LEN] for i in range(0, len(data), STATUSTEXT_LEN)]
    if len(parts[-1]) == STATUSTEXT_LEN:
        parts.append(b"")
    return [mavlink.MAVLink_statustext_message(severity, p, chunk_id, seq) for seq, p in enumerate(parts)]


def command_ack(command: int, result: int, target_system: int, target_component: int,
                progress: int = 0, result_param2: int = 0):
    return mavlink.MAVLink_command_ack_message(command, result, progress, result_param2, target_system,
                                               target_component)


def param_value(name: str, value: float, index: int, count: int):
    return mavlink.MAVLink_param_value_message(name.encode("ascii"), float(value), mavlink.MAV_PARAM_TYPE_REAL32,
                                               count, index)


def message_interval(message_id: int, interval_us: int):
    return mavlink.MAVLink_message_interval_message(message_id, interval_us)


def timesync_reply(now_ns: int, ts1: int):
    return mavlink.MAVLink_timesync_message(now_ns, ts1)
