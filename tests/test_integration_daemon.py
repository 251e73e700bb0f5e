"""`ahrsd run` as a subprocess on the simulated chip, driven by a pymavlink client on loopback.

One daemon serves the whole module (start-up costs a few seconds); tests that change its state run last or
restore it. Rates are measured from arrival times over a few seconds (±10 %).
"""

from __future__ import annotations

import math
import os
import re
import signal
import statistics
import time

import numpy as np
import pytest

os.environ["MAVLINK20"] = "1"
os.environ["MAVLINK_DIALECT"] = "ardupilotmega"

from ahrsd.daemon.mavlink_io import mavlink  # noqa: E402  (selects MAVLink 2 / ardupilotmega)
from support.ahrsd_process import GCS_COMP, GCS_SYS, LOW_RATE, OUR_COMP, Daemon  # noqa: E402
from support.daemon_stamps import stamps_s  # noqa: E402

from ahrsd.calibration.models import Calibration  # noqa: E402
from ahrsd.calibration.store import CalibrationStore
from ahrsd.daemon import gyro_cal  # noqa: E402
from ahrsd.drivers import registers as R  # noqa: E402
from ahrsd.simulation import open_stream  # noqa: E402
from bench.sim_calibration import sim_chip_mag_model  # noqa: E402

def assert_sent_at(stamps: list[tuple[float, object]], hz: float) -> None:
    """The rate the daemon sent at, from its own time stamps (time_boot_ms / time_usec: no delivery jitter),
    skipping the first 0.5 s (what was sent before a rate change can still be arriving): never above the rate,
    and not below half of it (a starved daemon on a loaded machine drops what it cannot send in time)."""
    t = np.array([m.time_boot_ms * 1e-3 if hasattr(m, "time_boot_ms") else m.time_usec * 1e-6 for _, m in stamps])
    t = t[t >= t[0] + 0.5]
    assert t.size >= 2, t
    sent_hz = (t.size - 1) / (t[-1] - t[0])
    assert 0.5 * hz <= sent_hz <= 1.1 * hz, (sent_hz, hz)


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    # the status line on (its log file: one line a second with the measured rate) for the rate test below
    d = Daemon(tmp_path_factory.mktemp("ahrsd"), *LOW_RATE, "--status-line", "on", mag_calibrated=True)
    try:
        d.wait_active()
        yield d
    finally:
        d.stop()


def test_outputs_arrive_at_their_default_rates(daemon):
    """The exact default rates are checked on a stepped clock (test_default_output_rates.py); here, in real
    time, every default output arrives, never faster than its rate, and at least at half of it: bounds that
    hold on a loaded machine (a starved daemon drops what it cannot send in time), yet fail for an output that
    is missing, sent per sample or throttled to a fraction of its rate. A stamped output is counted in the
    daemon's clock (its send or sample time stamps, support/daemon_stamps.py) over a window that starts after
    the collection did and ends before it does: what was queued before, or received late, is neither in nor out
    by when this process read it. HEARTBEAT and SYS_STATUS carry no stamp: counted as received."""
    window_s, lead_s, tail_s = 6.0, 0.5, 1.5
    t_start = time.monotonic()
    got = daemon.collect(lead_s + window_s + tail_s)
    w0, w1 = t_start + lead_s, t_start + lead_s + window_s
    stamped = {"ATTITUDE": 50.0, "ATTITUDE_QUATERNION": 10.0, "VISION_POSITION_ESTIMATE": 30.0, "HIGHRES_IMU": 10.0}
    for name, hz in stamped.items():
        assert name in got, f"no {name} in {sorted(got)}"
        n = sum(1 for t in stamps_s(got[name]) if w0 <= t < w1)
        assert 0.5 * hz * window_s - 1 <= n <= 1.1 * hz * window_s + 2, (name, n)
    collected_s = lead_s + window_s + tail_s
    for name, hz in {"SYS_STATUS": 1.0, "HEARTBEAT": 1.0}.items():
        assert name in got, f"no {name} in {sorted(got)}"
        n = len(got[name])
        # a late reader can receive, inside the collection, what was queued in the socket before it began
        assert 0.5 * hz * collected_s - 1 <= n <= 1.1 * hz * collected_s + 2, (name, n)
    assert "SCALED_IMU" not in got   # off by default


def truth_static():
    """Truth of the 'static' scenario (simulator, scipy; independent of the estimator's maths)."""
    from scipy.spatial.transform import Rotation

    from ahrsd.core.wmm import earth_field
    from ahrsd.simulation import DEFAULT_SITE, open_stream

    block = open_stream("static", seed=0).next_block(1)
    w, x, y, z = block.truth_q_wxyz[0]
    yaw, pitch, roll = Rotation.from_quat([x, y, z, w]).as_euler("ZYX")
    site = DEFAULT_SITE
    field = earth_field(site.lat_deg, site.lon_deg, site.alt_m, site.date)
    return roll, pitch, yaw, field


def angle_diff(a: float, b: float) -> float:
    return abs(math.remainder(a - b, 2 * math.pi))


def test_fields_units_and_frames_match_the_simulator(daemon):
    roll, pitch, yaw, field = truth_static()
    got = daemon.collect(1.5)
    att = got["ATTITUDE"][-1][1]
    # attitude within the estimator's accuracy on an uncalibrated simulated ADIS16405 (datasheet errors)
    assert angle_diff(att.roll, roll) < math.radians(1.5)
    assert angle_diff(att.pitch, pitch) < math.radians(1.5)
    assert angle_diff(att.yaw, yaw) < math.radians(3.0)        # TRUE heading: declination applied
    assert -math.pi <= att.yaw <= math.pi
    assert max(abs(att.rollspeed), abs(att.pitchspeed), abs(att.yawspeed)) < math.radians(2)
    # ATTITUDE_QUATERNION is the same attitude (true north), scalar first
    q = got["ATTITUDE_QUATERNION"][-1][1]
    qw, qx, qy, qz = q.q1, q.q2, q.q3, q.q4
    assert math.isclose(qw * qw + qx * qx + qy * qy + qz * qz, 1.0, abs_tol=1e-5)
    q_yaw = math.atan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz))
    assert angle_diff(q_yaw, yaw) < math.radians(3.0)
    # VISION_POSITION_ESTIMATE: zero finite position, true yaw, finite covariance with the filter's variances
    vpe = got["VISION_POSITION_ESTIMATE"][-1][1]
    assert (vpe.x, vpe.y, vpe.z) == (0.0, 0.0, 0.0)
    assert angle_diff(vpe.yaw, yaw) < math.radians(3.0)
    cov = np.array(vpe.covariance)
    assert np.all(np.isfinite(cov))
    assert 0.0 < cov[20] < math.radians(10) ** 2     # yaw variance (rad²) from the filter
    assert abs(vpe.usec / 1e6 - time.monotonic()) < 2.0   # CLOCK_MONOTONIC µs, like our TIMESYNC
    usecs = [m.usec for _, m in got["VISION_POSITION_ESTIMATE"]]
    assert all(b > a for a, b in zip(usecs, usecs[1:]))
    # HIGHRES_IMU: SI + gauss, sensor at rest
    imu = got["HIGHRES_IMU"][-1][1]
    acc = np.array([imu.xacc, imu.yacc, imu.zacc])
    mag_gauss = np.array([imu.xmag, imu.ymag, imu.zmag])
    assert np.linalg.norm(acc) == pytest.approx(9.81, abs=0.3)
    assert imu.zacc < -9.0                     # FRD at rest, level: specific force points up (−z)
    assert np.linalg.norm(mag_gauss) == pytest.approx(field.total_ut / 100.0, rel=0.15)
    assert imu.fields_updated == 0x11FF
    st = got["SYS_STATUS"][-1][1]
    bits = 0x1 | 0x2 | 0x4 | 0x200000
    assert st.onboard_control_sensors_present & bits == bits
    assert st.onboard_control_sensors_health & bits == bits
    hb = got["HEARTBEAT"][-1][1]
    assert (hb.type, hb.autopilot) == (mavlink.MAV_TYPE_IMU, mavlink.MAV_AUTOPILOT_INVALID)


def test_unknown_targeted_command_is_unsupported_and_broadcast_is_ignored(daemon):
    daemon.command(mavlink.MAV_CMD_DO_SET_MODE, 1)
    ack = daemon.ack(mavlink.MAV_CMD_DO_SET_MODE)
    assert ack is not None and ack.result == mavlink.MAV_RESULT_UNSUPPORTED
    assert (ack.target_system, ack.target_component) == (GCS_SYS, GCS_COMP)
    daemon.command(mavlink.MAV_CMD_DO_SET_SERVO, 1, 1500, target_component=0)
    assert daemon.ack(mavlink.MAV_CMD_DO_SET_SERVO, timeout=1.0) is None


def test_message_interval_set_get_and_restore(daemon):
    daemon.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_ATTITUDE, 100_000)
    assert daemon.ack(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL).result == mavlink.MAV_RESULT_ACCEPTED
    daemon.command(mavlink.MAV_CMD_GET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_ATTITUDE)
    assert daemon.ack(mavlink.MAV_CMD_GET_MESSAGE_INTERVAL).result == mavlink.MAV_RESULT_ACCEPTED
    mi = daemon.recv("MESSAGE_INTERVAL", 5.0)
    assert (mi.message_id, mi.interval_us) == (mavlink.MAVLINK_MSG_ID_ATTITUDE, 100_000)
    got = daemon.collect(4.0)
    assert_sent_at(got["ATTITUDE"], 10.0)
    # SCALED_IMU on at 20 Hz, then disable it again (−1) and ATTITUDE back to its default (0)
    daemon.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_SCALED_IMU, 50_000)
    assert daemon.ack(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL).result == mavlink.MAV_RESULT_ACCEPTED
    got = daemon.collect(3.0)
    assert_sent_at(got["SCALED_IMU"], 20.0)
    s = got["SCALED_IMU"][-1][1]
    assert math.hypot(s.xacc, s.yacc, s.zacc) == pytest.approx(1000, rel=0.05)   # mG
    for mid, interval in ((mavlink.MAVLINK_MSG_ID_SCALED_IMU, -1), (mavlink.MAVLINK_MSG_ID_ATTITUDE, 0)):
        daemon.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mid, interval)
        assert daemon.ack(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL).result == mavlink.MAV_RESULT_ACCEPTED
    # out of range: VISION_POSITION_ESTIMATE faster than 50 Hz, and a message we do not publish
    daemon.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_VISION_POSITION_ESTIMATE, 10_000)
    assert daemon.ack(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL).result == mavlink.MAV_RESULT_DENIED
    daemon.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_GPS_RAW_INT, 100_000)
    assert daemon.ack(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL).result == mavlink.MAV_RESULT_DENIED
    got = daemon.collect(3.0)
    assert "SCALED_IMU" not in got
    assert_sent_at(got["ATTITUDE"], 50.0)


def test_request_message(daemon):
    daemon.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
    assert daemon.ack(mavlink.MAV_CMD_REQUEST_MESSAGE).result == mavlink.MAV_RESULT_ACCEPTED
    av = daemon.recv("AUTOPILOT_VERSION", 5.0)
    assert av is not None and av.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    daemon.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION)
    assert daemon.ack(mavlink.MAV_CMD_REQUEST_MESSAGE).result == mavlink.MAV_RESULT_ACCEPTED
    assert daemon.recv("ATTITUDE_QUATERNION", 5.0) is not None
    daemon.command(mavlink.MAV_CMD_REQUEST_MESSAGE, 999)
    assert daemon.ack(mavlink.MAV_CMD_REQUEST_MESSAGE).result == mavlink.MAV_RESULT_DENIED


def test_gyro_calibration_and_duplicate_command(daemon):
    """PREFLIGHT_CALIBRATION gyro: IN_PROGRESS, a re-sent duplicate gets the same ACK (not a restart),
    then exactly one final ACCEPTED; the new calibration is saved in the state directory."""
    cmd = mavlink.MAV_CMD_PREFLIGHT_CALIBRATION
    daemon.command(cmd, 1)
    first = daemon.ack(cmd)
    assert first.result == mavlink.MAV_RESULT_IN_PROGRESS
    daemon.command(cmd, 1, confirmation=1)
    dup = daemon.ack(cmd)
    assert dup.result == mavlink.MAV_RESULT_IN_PROGRESS
    final = daemon.ack(cmd, timeout=15.0)
    assert final is not None and final.result == mavlink.MAV_RESULT_ACCEPTED, daemon.output()
    assert daemon.ack(cmd, timeout=1.0) is None        # no second calibration ran
    # the saved bias is the simulated chip's turn-on bias (static scenario: no rotation at all), to within its
    # in-run bias instability (σ 0.007 °/s, Gauss-Markov) and the noise of the averaging window
    saved = CalibrationStore(daemon.state_dir).load()
    sim_errors = open_stream("static", seed=0).errors           # the daemon's --sim static, default seed 0
    # the mean of DURATION_S of samples has σ = per-sample noise / sqrt(N) (0.954 °/s at 819.2 SPS -> 0.024 °/s
    # over 2 s, the same at the daemon's rate: the white noise's σ goes with sqrt(rate)): allow 4σ of that plus
    # 3σ of the in-run instability (a sign error is off by 2|bias| ≈ 0.4 °/s)
    rate_hz = R.nearest_rate_hz(float(LOW_RATE[1]))
    n = gyro_cal.DURATION_S * rate_hz
    atol = 4 * sim_errors.noise_std(rate_hz)["gyro_rad_s"] / math.sqrt(n) + 3 * math.radians(0.007)
    np.testing.assert_allclose(saved.gyro.bias_rad_s, sim_errors.gyro_bias_rad_s, atol=atol)
    np.testing.assert_array_equal(saved.gyro.matrix, np.eye(3))  # bias only: scale and misalignment kept
    identity = Calibration.identity()
    # the magnetometer calibration the daemon started with (Daemon(mag_calibrated=True)) is kept
    assert saved.mag.to_dict() == sim_chip_mag_model().to_dict() and saved.accel.to_dict() == identity.accel.to_dict()


def test_parameter_protocol(daemon):
    g = daemon.gcs
    g.mav.param_request_list_send(daemon.sysid, 0)       # QGC asks with MAV_COMP_ID_ALL
    values = {}
    end = time.monotonic() + 3
    count = None
    while time.monotonic() < end and (count is None or len(values) < count):
        m = daemon.recv("PARAM_VALUE", 1.0)
        if m is None:
            break
        count = m.param_count
        assert m.param_type == mavlink.MAV_PARAM_TYPE_REAL32
        values[m.param_index] = (m.param_id, m.param_value)
    assert count and len(values) == count and sorted(values) == list(range(count))
    names = {name: v for name, v in values.values()}
    assert names["SR_VISION_POS"] == 30.0 and names["SR_ATTITUDE"] == 50.0
    # read by name
    g.mav.param_request_read_send(daemon.sysid, OUR_COMP, b"SR_HIGHRES_IMU", -1)
    m = daemon.recv("PARAM_VALUE", 5.0)
    assert m.param_id == "SR_HIGHRES_IMU" and m.param_value == 10.0
    # unknown parameter: STATUSTEXT, no PARAM_VALUE
    g.mav.param_request_read_send(daemon.sysid, OUR_COMP, b"NO_SUCH_PARAM", -1)
    st = daemon.recv("STATUSTEXT", 2.0, lambda m: "NO_SUCH_PARAM" in m.text)
    assert st is not None
    # out of range write: refused, answered with the value in force
    g.mav.param_set_send(daemon.sysid, OUR_COMP, b"SR_VISION_POS", 100.0, mavlink.MAV_PARAM_TYPE_REAL32)
    m = daemon.recv("PARAM_VALUE", 2.0, lambda m: m.param_id == "SR_VISION_POS")
    assert m.param_value == 30.0
    # good write: applied (rate changes), answered, persisted
    g.mav.param_set_send(daemon.sysid, OUR_COMP, b"SR_HIGHRES_IMU", 25.0, mavlink.MAV_PARAM_TYPE_REAL32)
    m = daemon.recv("PARAM_VALUE", 2.0, lambda m: m.param_id == "SR_HIGHRES_IMU")
    assert m.param_value == 25.0
    got = daemon.collect(3.0)
    assert_sent_at(got["HIGHRES_IMU"], 25.0)
    assert '"SR_HIGHRES_IMU": 25.0' in (daemon.state_dir / "params.json").read_text()
    g.mav.param_set_send(daemon.sysid, OUR_COMP, b"SR_HIGHRES_IMU", 10.0, mavlink.MAV_PARAM_TYPE_REAL32)
    assert daemon.recv("PARAM_VALUE", 2.0, lambda m: m.param_id == "SR_HIGHRES_IMU").param_value == 10.0


def test_the_daemon_reads_the_chip_at_the_rate_it_set(daemon):
    """`ahrsd run --rate-hz 204.8` (LOW_RATE): the status line's measured rate is the chip's 1638.404 / 8 = 204.8
    SPS, not the 819.2 of a chip left at its default (median of the last five 1 s windows: a window can miss or
    catch up a block). The datasheet's SMPL_PRD for each rate: tests/test_sensor_rate.py."""
    end = time.monotonic() + 30.0
    while len(rates := [float(x) for x in re.findall(r"(\d+\.\d) SPS", daemon.output())]) < 5 \
            and time.monotonic() < end:
        daemon.collect(1.0)
    assert len(rates) >= 5, daemon.output()[-2000:]
    assert statistics.median(rates[-5:]) == pytest.approx(float(LOW_RATE[1]), rel=0.1), rates[-5:]


def test_timesync_is_answered(daemon):
    ts1 = 123456789
    daemon.gcs.mav.timesync_send(0, ts1)
    m = daemon.recv("TIMESYNC", 2.0, lambda m: m.ts1 == ts1)
    assert m is not None
    assert abs(m.tc1 - time.monotonic_ns()) < 2e9      # our CLOCK_MONOTONIC in ns (same machine)


def test_malformed_input_is_counted_not_fatal(daemon):
    sock = daemon.gcs.port
    addr = next(iter(daemon.gcs.clients))      # the daemon's udpout socket
    before = daemon.recv("SYS_STATUS", 6.0).errors_comm
    sock.sendto(b"\xfd\x09\x00\x00\x00garbage-not-mavlink", addr)
    frame = bytearray(daemon.gcs.mav.heartbeat_encode(6, 8, 0, 0, 0).pack(daemon.gcs.mav))
    frame[-1] ^= 0xFF                                   # bad CRC
    sock.sendto(bytes(frame), addr)
    sock.sendto(bytes(range(256)) * 4, addr)
    time.sleep(1.2)
    after = daemon.recv("SYS_STATUS", 6.0).errors_comm
    assert after >= before + 2
    daemon.wait_active(5.0)


def test_system_id_latches_to_the_autopilot_then_sigterm_shuts_down(daemon):
    """The module's daemon (no daemon start of its own): the last test, since it latches the system id and
    stops the daemon."""
    d = daemon
    try:
        d.wait_active(30.0)
        # play the autopilot (system 7) on the same link: an armed ArduPilot heartbeat
        d.gcs.mav.srcSystem, d.gcs.mav.srcComponent = 7, 1
        d.gcs.mav.heartbeat_send(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                 mavlink.MAV_MODE_FLAG_SAFETY_ARMED, 0, mavlink.MAV_STATE_ACTIVE)
        hb = d.recv("HEARTBEAT", 8.0, lambda m: m.get_srcSystem() == 7)
        assert hb is not None
        d.sysid = 7
        # armed now: gyro calibration is refused
        d.gcs.mav.srcSystem, d.gcs.mav.srcComponent = GCS_SYS, GCS_COMP
        d.command(mavlink.MAV_CMD_PREFLIGHT_CALIBRATION, 1)
        assert d.ack(mavlink.MAV_CMD_PREFLIGHT_CALIBRATION).result == mavlink.MAV_RESULT_TEMPORARILY_REJECTED
        d.proc.send_signal(signal.SIGTERM)
        st = d.recv("STATUSTEXT", 5.0, lambda m: "stopping" in m.text)
        assert st is not None
        off = d.recv("HEARTBEAT", 3.0, lambda m: m.system_status == mavlink.MAV_STATE_POWEROFF)
        assert off is not None
        assert d.proc.wait(10) == 0
    finally:
        d.stop()
