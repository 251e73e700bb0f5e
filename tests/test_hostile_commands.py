"""Valid MAVLink frames with hostile contents, on the real receive path of an in-process daemon: the three
findings of the hostile-frame review, and the refusal rules every handler follows (the right MAV_RESULT, a
counted and rate-limited warning, nothing raised — `handler_errors` stays 0, no traceback logged).

Truth for the fixed-yaw calibration is the hard iron injected into the synthetic data (tests/support/field_data),
never the code under test.
"""

from __future__ import annotations

import logging
from types import SimpleNamespace

import numpy as np
import pytest

from ahrsd.calibration.models import Calibration, MagModel
from ahrsd.core.sample import make_sample
from ahrsd.daemon.magcal import CMD_FIXED_YAW
from ahrsd.daemon.mavlink_io import mavlink
from service_rig import gcs_socket, start_service, stop_service
from support.field_data import HARD_IRON_UT, MAG_NOISE_UT, SOFT_DISTORTION, trajectory
from support.mavlink_feed import drain, feed

OUR_SYS, OUR_COMP = 1, 200
INT32_MAX, INT32_MIN = 2**31 - 1, -2**31
RATE_HZ = 50.0
SITE_LAT, SITE_LON = 35.7, 51.4          # where support.field_data.SITE is (its WMM field made the data)


class _Records(logging.Handler):
    def __init__(self):
        super().__init__(logging.DEBUG)
        self.records: list[logging.LogRecord] = []

    def emit(self, record):
        self.records.append(record)

    def tracebacks(self):
        return [r.getMessage() for r in self.records if r.exc_info]


@pytest.fixture
def rig(tmp_path):
    gcs = gcs_socket(rcvbuf=1 << 22)
    clock = [1000.0]        # the daemon's clock (the commands' duplicate window among them), moved by the test
    service, loop = start_service(gcs, tmp_path / "state", clock=lambda: clock[0])
    logs = _Records()
    logging.getLogger("ahrsd").addHandler(logs)
    rig = SimpleNamespace(service=service, loop=loop, gcs=gcs, ep=service.endpoints[0], logs=logs,
                          sender=mavlink.MAVLink(None, srcSystem=255, srcComponent=190))
    rig.clock = clock
    yield rig
    logging.getLogger("ahrsd").removeHandler(logs)
    stop_service(service, loop)
    gcs.close()


def command_long(rig, command, *params):
    p = list(params) + [0.0] * (7 - len(params))
    return rig.sender.command_long_encode(OUR_SYS, OUR_COMP, command, 0, *p).pack(rig.sender)


def command_int(rig, command, p1=0.0, p2=0.0, p3=0.0, p4=0.0, x=0, y=0, z=0.0, frame=0):
    return rig.sender.command_int_encode(OUR_SYS, OUR_COMP, frame, command, 0, 0, p1, p2, p3, p4, x, y,
                                         z).pack(rig.sender)


def acks(messages, command):
    return [m for m in messages if m.get_type() == "COMMAND_ACK" and m.command == command]


def assert_no_escape(rig):
    assert rig.service.commands.counters.handler_errors == 0
    assert not rig.logs.tracebacks()


# ------------------------------------------------------------------------------------------ finding 1


def test_request_message_as_command_int_reads_z_as_param7(rig):
    """REQUEST_MESSAGE as COMMAND_INT: param7 (response target) is `z` there — no AttributeError, a real answer."""
    drain(rig)
    feed(rig, command_int(rig, mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION, z=1.0))
    got = drain(rig)
    (ack,) = acks(got, mavlink.MAV_CMD_REQUEST_MESSAGE)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED
    assert [m for m in got if m.get_type() == "AUTOPILOT_VERSION"]
    # ATTITUDE (id 30) with no estimate yet: a protocol answer, not a handler failure
    feed(rig, command_int(rig, mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_ATTITUDE))
    (ack,) = acks(drain(rig), mavlink.MAV_CMD_REQUEST_MESSAGE)
    assert ack.result == mavlink.MAV_RESULT_TEMPORARILY_REJECTED
    # a response target outside 0..2 is refused, as a COMMAND_INT z as well as a COMMAND_LONG param7
    feed(rig, command_int(rig, mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION, z=7.0))
    feed(rig, command_long(rig, mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION,
                           0, 0, 0, 0, 0, float("nan")))
    assert [a.result for a in acks(drain(rig), mavlink.MAV_CMD_REQUEST_MESSAGE)] == [mavlink.MAV_RESULT_DENIED] * 2
    assert rig.service.commands.counters.refused == 2
    assert_no_escape(rig)


def test_preflight_calibration_of_the_magnetometer_starts_and_accepts_through_the_daemon(rig):
    """PREFLIGHT_CALIBRATION param2 = 76 (force save) with nothing finished, then param2 = 1 (start), on the
    daemon's receive path, delegated to the field calibration (daemon.builtin_commands → daemon.magcal): FAILED
    then ACCEPTED and a session running, nothing raised (a delegated handler that raised answered FAILED for
    both and started nothing)."""
    drain(rig)
    feed(rig, command_long(rig, mavlink.MAV_CMD_PREFLIGHT_CALIBRATION, 0, 76))
    feed(rig, command_long(rig, mavlink.MAV_CMD_PREFLIGHT_CALIBRATION, 0, 1))
    got = drain(rig)
    assert [a.result for a in acks(got, mavlink.MAV_CMD_PREFLIGHT_CALIBRATION)] == [
        mavlink.MAV_RESULT_FAILED, mavlink.MAV_RESULT_ACCEPTED]
    assert rig.service.magcal.calibrating
    assert_no_escape(rig)


# ------------------------------------------------------------------------------------------ fixed yaw


def feed_still_samples(rig, t0_s: float, duration_s: float, seed: int = 0) -> float:
    """A still sensor (roll 4°, pitch −3°, true heading 30°) into the mag-cal listener, each sample calibrated
    with the calibration in force when it arrives (as the pipeline does). Returns the next sample time."""
    t = t0_s + np.arange(0.0, duration_s, 1.0 / RATE_HZ)
    traj = trajectory(t, np.full_like(t, np.radians(4.0)), np.full_like(t, np.radians(-3.0)),
                      np.full_like(t, np.radians(30.0)), seed=seed)
    proto = rig.service.magcal
    for i in range(len(t)):
        cal = rig.service.pipeline.calibration
        proto.on_sample(make_sample(t[i], np.zeros(3), traj.accel[i], cal.mag.apply(traj.raw[i])),
                        SimpleNamespace(roll_rad=traj.roll[i], pitch_rad=traj.pitch[i], yaw_rad=0.0,
                                        rate_body_rad_s=np.zeros(3), gyro_bias_rad_s=np.zeros(3)))
    return float(t[-1] + 1.0 / RATE_HZ)


@pytest.fixture
def stale_hard_iron(rig):
    """Soft iron right, hard iron stale (zero): the fixed-yaw calibration has the injected hard iron to find."""
    soft = np.linalg.inv(SOFT_DISTORTION)
    rig.service.apply_calibration(Calibration.identity().with_sensor("mag", MagModel(np.zeros(3), soft)),
                                  save=False)
    n_averaged = int(rig.service.magcal.settings.fixed_yaw_average_s * RATE_HZ)
    return 5 * MAG_NOISE_UT / np.sqrt(n_averaged)          # 5 σ of the window mean, per axis


def test_fixed_yaw_latitude_214_is_denied_up_front(rig, stale_hard_iron):
    feed_still_samples(rig, 0.0, 1.5)
    before = rig.service.pipeline.calibration
    drain(rig)
    feed(rig, command_long(rig, CMD_FIXED_YAW, 30.0, 0, 214.0, 10.0))
    got = drain(rig)
    (ack,) = acks(got, CMD_FIXED_YAW)
    assert ack.result == mavlink.MAV_RESULT_DENIED
    texts = [m.text for m in got if m.get_type() == "STATUSTEXT"]
    assert any("latitude 214" in t for t in texts), texts     # the one-line reason reaches the operator
    assert rig.service.pipeline.calibration is before
    assert rig.service.commands.counters.refused == 1
    assert_no_escape(rig)


FIRST_BEYOND_EACH_LIMIT = [     # (form, params, MAV_RESULT, the reason's words)
    ("long", (30.0, 0, 90.5, 10.0), mavlink.MAV_RESULT_DENIED, "latitude 90.5"),        # just beyond a pole
    ("long", (30.0, 0, 35.7, 180.5), mavlink.MAV_RESULT_DENIED, "longitude 180.5"),
    ("long", (30.0, 1.5, 0.0, 0.0), mavlink.MAV_RESULT_FAILED, "mask 1.5"),             # a mask is a whole number
    ("long", (360.5, 0, 0.0, 0.0), mavlink.MAV_RESULT_DENIED, "yaw 360.5 deg invalid"),  # a yaw is within ±360°
    ("int", dict(x=357_000_000, y=514_000_000, frame=mavlink.MAV_FRAME_LOCAL_NED), mavlink.MAV_RESULT_DENIED,
     "frame 1 not global"),                                                              # x/y are no lat/lon there
]


def test_fixed_yaw_just_outside_each_limit_is_refused_with_its_reason(rig, stale_hard_iron):
    """Each input check of MAV_CMD_FIXED_MAG_CAL_YAW at the first value beyond its limit (the cases above are far
    beyond): the MAVLink limits (common.xml: latitude ±90°, longitude ±180°, a compass bitmask, x/y a position only
    in a global frame) and the yaw range daemon/magcal.py states (±360°),
    not what the code happens to accept. One daemon for all (each request differs, so none is
    a duplicate of another)."""
    feed_still_samples(rig, 0.0, 1.5)
    before = rig.service.pipeline.calibration
    for form, params, result, reason in FIRST_BEYOND_EACH_LIMIT:
        drain(rig)
        feed(rig, command_long(rig, CMD_FIXED_YAW, *params) if form == "long" else
             command_int(rig, CMD_FIXED_YAW, 30.0, **params))
        got = drain(rig)
        (ack,) = acks(got, CMD_FIXED_YAW)
        assert ack.result == result, reason
        said = "".join(m.text for m in got if m.get_type() == "STATUSTEXT")     # chunked above 50 bytes
        assert reason in said, (reason, said)
        rig.clock[0] += 10.0                  # past the STATUSTEXT rate limit: each refusal says why
    assert rig.service.pipeline.calibration is before
    assert rig.service.commands.counters.refused == len(FIRST_BEYOND_EACH_LIMIT)
    assert_no_escape(rig)


def test_fixed_yaw_int32_extremes_in_command_int_are_read_as_position_and_denied(rig, stale_hard_iron):
    """The COMMAND_INT of the finding: x = 2^31−1, y = −2^31 are degE7 (214.7°, −214.7°): DENIED, unchanged."""
    feed_still_samples(rig, 0.0, 1.5)
    before = rig.service.pipeline.calibration
    drain(rig)
    feed(rig, command_int(rig, CMD_FIXED_YAW, x=INT32_MAX, y=INT32_MIN))
    (ack,) = acks(drain(rig), CMD_FIXED_YAW)
    assert ack.result == mavlink.MAV_RESULT_DENIED
    assert rig.service.pipeline.calibration is before
    assert_no_escape(rig)


def test_fixed_yaw_twice_in_a_row_gives_the_same_calibration(rig, stale_hard_iron):
    """A COMMAND_LONG, then ~20 ms later the same request as COMMAND_INT (a retry in the other form: a duplicate,
    answered without re-running), then the request re-run 20 ms after each swap — once with the position as
    COMMAND_INT x/y: every result is the injected hard iron, never twice it (the samples of the averaging
    window were calibrated with the model the previous request replaced)."""
    tolerance_ut = stale_hard_iron
    t = feed_still_samples(rig, 0.0, 1.5)
    drain(rig)
    feed(rig, command_long(rig, CMD_FIXED_YAW, 30.0, 0, SITE_LAT, SITE_LON))
    assert acks(drain(rig), CMD_FIXED_YAW)[-1].result == mavlink.MAV_RESULT_ACCEPTED
    first = rig.service.pipeline.calibration.mag.hard_iron_ut.copy()
    np.testing.assert_allclose(first, HARD_IRON_UT, atol=tolerance_ut)

    t = feed_still_samples(rig, t, 0.02, seed=1)
    rig.clock[0] += 0.02
    feed(rig, command_int(rig, CMD_FIXED_YAW, 30.0, 0, SITE_LAT, SITE_LON))
    assert acks(drain(rig), CMD_FIXED_YAW)[-1].result == mavlink.MAV_RESULT_ACCEPTED
    assert rig.service.commands.counters.duplicates == 1
    np.testing.assert_array_equal(rig.service.pipeline.calibration.mag.hard_iron_ut, first)

    for i, frame in enumerate((command_long(rig, CMD_FIXED_YAW, 30.0, 0, SITE_LAT, SITE_LON),
                               command_int(rig, CMD_FIXED_YAW, 30.0, 0, 0, 0, x=round(SITE_LAT * 1e7),
                                           y=round(SITE_LON * 1e7)))):
        rig.clock[0] += 10.0                        # outside the duplicate window: run again
        t = feed_still_samples(rig, t, 0.02, seed=2 + i)
        feed(rig, frame)
        assert acks(drain(rig), CMD_FIXED_YAW)[-1].result == mavlink.MAV_RESULT_ACCEPTED
        np.testing.assert_allclose(rig.service.pipeline.calibration.mag.hard_iron_ut, HARD_IRON_UT,
                                   atol=tolerance_ut)
    assert_no_escape(rig)


def test_fixed_yaw_position_as_command_int_equals_command_long(rig, stale_hard_iron):
    """The one parameter view: the site as COMMAND_LONG param3/4 (deg) and as COMMAND_INT x/y (degE7) give
    the same WMM reference, hence the same hard iron."""
    feed_still_samples(rig, 0.0, 1.5)
    feed(rig, command_long(rig, CMD_FIXED_YAW, 30.0, 0, SITE_LAT, SITE_LON))
    by_long = rig.service.pipeline.calibration.mag.hard_iron_ut.copy()
    rig.clock[0] += 10.0
    feed(rig, command_int(rig, CMD_FIXED_YAW, 30.0, 0, 0, 0, x=round(SITE_LAT * 1e7), y=round(SITE_LON * 1e7)))
    np.testing.assert_allclose(rig.service.pipeline.calibration.mag.hard_iron_ut, by_long, atol=1e-3)
    # x/y in a frame that does not make them a latitude/longitude (MAV_FRAME_LOCAL_NED = 1): refused
    rig.clock[0] += 10.0
    feed(rig, command_int(rig, CMD_FIXED_YAW, 30.0, 0, 0, 0, x=round(SITE_LAT * 1e7), y=round(SITE_LON * 1e7),
                          frame=mavlink.MAV_FRAME_LOCAL_NED))
    assert [a.result for a in acks(drain(rig), CMD_FIXED_YAW)] == [mavlink.MAV_RESULT_ACCEPTED] * 2 + [
        mavlink.MAV_RESULT_DENIED]
    # a different site must give a different reference: the x/y were read, not ignored
    rig.clock[0] += 10.0
    feed(rig, command_int(rig, CMD_FIXED_YAW, 30.0, 0, 0, 0, x=-33 * 10**7, y=151 * 10**7))
    assert np.linalg.norm(rig.service.pipeline.calibration.mag.hard_iron_ut - by_long) > 1.0
    assert [a.result for a in acks(drain(rig), CMD_FIXED_YAW)] == [mavlink.MAV_RESULT_ACCEPTED]
    assert_no_escape(rig)


def test_fixed_yaw_is_refused_while_armed_and_warns_of_a_field_far_from_the_wmm(rig, stale_hard_iron):
    """Armed: TEMPORARILY_REJECTED with "Disarm", unchanged. Disarmed: the stale model (hard iron 21 µT off) is
    farther than FIXED_YAW_FIELD_MISMATCH_WARN_MGAUSS from the WMM's strength, so the new one comes with a warning
    to run a full calibration; run again on the model it found (within the noise of the WMM's), no warning."""
    feed_still_samples(rig, 0.0, 1.5)
    before = rig.service.pipeline.calibration
    rig.service.autopilot.armed = True
    drain(rig)
    feed(rig, command_long(rig, CMD_FIXED_YAW, 30.0, 0, SITE_LAT, SITE_LON))
    got = drain(rig)
    assert [a.result for a in acks(got, CMD_FIXED_YAW)] == [mavlink.MAV_RESULT_TEMPORARILY_REJECTED]
    assert any("Disarm" in m.text for m in got if m.get_type() == "STATUSTEXT")
    assert rig.service.pipeline.calibration is before
    rig.service.autopilot.armed = False
    for stale in (True, False):
        rig.clock[0] += 10.0                        # outside the duplicate window
        feed(rig, command_long(rig, CMD_FIXED_YAW, 30.0, 0, SITE_LAT, SITE_LON))
        got = drain(rig)
        assert [a.result for a in acks(got, CMD_FIXED_YAW)] == [mavlink.MAV_RESULT_ACCEPTED]
        warned = [m.text for m in got if m.get_type() == "STATUSTEXT" and "mG off WMM" in m.text]
        assert bool(warned) is stale, warned
    assert_no_escape(rig)


def test_fixed_yaw_position_in_both_forms_is_denied(rig, stale_hard_iron):
    """A COMMAND_INT with the position in param3/4 and in x/y: which one is meant cannot be told, so neither is
    taken (DENIED, the reason to the operator, the calibration unchanged) — even when the two agree."""
    feed_still_samples(rig, 0.0, 1.5)
    before = rig.service.pipeline.calibration
    drain(rig)
    feed(rig, command_int(rig, CMD_FIXED_YAW, 30.0, 0, SITE_LAT, SITE_LON, x=round(SITE_LAT * 1e7),
                          y=round(SITE_LON * 1e7)))
    got = drain(rig)
    assert [a.result for a in acks(got, CMD_FIXED_YAW)] == [mavlink.MAV_RESULT_DENIED]
    texts = [m.text for m in got if m.get_type() == "STATUSTEXT"]
    assert any("position in both" in t for t in texts), texts
    assert rig.service.pipeline.calibration is before
    assert_no_escape(rig)



# ------------------------------------------------------------------------------------------ parameter protocol


def param_set(rig, name: bytes, value: float, param_type: int = mavlink.MAV_PARAM_TYPE_REAL32) -> bytes:
    return rig.sender.param_set_encode(OUR_SYS, OUR_COMP, name, value, param_type).pack(rig.sender)


def test_sixteen_char_unterminated_param_id_is_read_as_sixteen_characters(rig):
    """A 16-character name fills param_id with no NUL: read as 16 characters, not overrun; refused, counted."""
    from ahrsd.daemon.params import decode_param_id

    assert decode_param_id(b"ABCDEFGHIJKLMNOP") == "ABCDEFGHIJKLMNOP"
    assert decode_param_id(b"ABCDEFGHIJKLMNOPQRS") == "ABCDEFGHIJKLMNOP"
    drain(rig)
    before = rig.service.params.rejected_writes
    feed(rig, param_set(rig, b"ABCDEFGHIJKLMNOP", 1.0))
    texts = [m.text for m in drain(rig) if m.get_type() == "STATUSTEXT"]
    assert any("ABCDEFGHIJKLMNOP" in t for t in texts)
    assert rig.service.params.rejected_writes == before + 1


def test_param_set_with_an_unknown_param_type_is_refused_and_answered_with_the_value_in_force(rig):
    value = rig.service.params.get("SR_ATTITUDE")
    drain(rig)
    feed(rig, param_set(rig, b"SR_ATTITUDE", 20.0, param_type=200))
    answers = [m for m in drain(rig) if m.get_type() == "PARAM_VALUE"]
    assert answers and answers[-1].param_value == value and rig.service.params.get("SR_ATTITUDE") == value
    assert rig.service.params.rejected_writes == 1
    feed(rig, param_set(rig, b"SR_ATTITUDE", 20.0, param_type=mavlink.MAV_PARAM_TYPE_UINT8))  # C-cast: fine
    assert rig.service.params.get("SR_ATTITUDE") == 20.0


def test_param_read_with_a_bad_index_or_name_is_counted_and_not_answered(rig):
    drain(rig)
    for index, name in ((-2, b"SR_ATTITUDE"), (len(rig.service.params), b""), (32767, b""),
                        (-1, b"\xff\x01BAD"), (-1, b"")):
        feed(rig, rig.sender.param_request_read_encode(OUR_SYS, OUR_COMP, name, index).pack(rig.sender))
    got = drain(rig)
    assert not [m for m in got if m.get_type() == "PARAM_VALUE"]
    assert rig.service.params.rejected_reads == 5
    texts = [m.text for m in got if m.get_type() == "STATUSTEXT"]
    assert all(t.isascii() and t.isprintable() for t in texts), texts   # a hostile name is not echoed raw
    assert_no_escape(rig)


# ------------------------------------------------------------------------------------------ autopilot position


def gps_raw_int(rig, lat_e7, lon_e7, alt_mm=100_000, fix_type=3, cog=0):
    return rig.sender.gps_raw_int_encode(0, fix_type, lat_e7, lon_e7, alt_mm, 100, 100, 0, cog, 10).pack(rig.sender)


def global_position_int(rig, lat_e7, lon_e7, alt_mm=100_000):
    return rig.sender.global_position_int_encode(0, lat_e7, lon_e7, alt_mm, 0, 0, 0, 0, 0).pack(rig.sender)


def test_hostile_autopilot_positions_are_refused_counted_and_do_not_step_the_heading(rig):
    """GPS_RAW_INT / GLOBAL_POSITION_INT from the autopilot feed the WMM declination: a latitude of 214°, the
    INT32_MAX "unknown" sentinel, an altitude of 2147 km or an unknown fix type are refused and counted; the
    declination (hence the true heading sent out) does not move and the periodic WMM lookup does not raise."""
    s = rig.service
    decl, resets = s.declination_rad, s.reset_counter
    hostile = [gps_raw_int(rig, 214 * 10**7, 10 * 10**7), gps_raw_int(rig, INT32_MAX, INT32_MAX),
               gps_raw_int(rig, 35 * 10**7, 51 * 10**7, alt_mm=INT32_MAX), gps_raw_int(rig, 35 * 10**7, 51 * 10**7,
                                                                                        fix_type=200),
               global_position_int(rig, INT32_MIN, 10 * 10**7), global_position_int(rig, 10 * 10**7, 181 * 10**7)]
    for data in hostile:
        feed(rig, data)
    drain(rig)
    assert s.autopilot.lat_deg is None and s.autopilot.rejected_positions == len(hostile)
    s.declination.resolve()                                           # what housekeeping runs every 10 s
    assert s.declination_rad == decl and s.reset_counter == resets
    feed(rig, gps_raw_int(rig, 35 * 10**7, 51 * 10**7, cog=40000))      # a course beyond 359.99°
    assert s.autopilot.rejected_courses == 1 and s.autopilot.course_rad is None
    # the valid position of the last frame was taken: the guard refuses only what cannot be true
    assert s.autopilot.lat_deg == pytest.approx(35.0) and s.autopilot.lon_deg == pytest.approx(51.0)
    warnings = [r for r in rig.logs.records if r.name == "ahrsd.daemon.autopilot"]
    assert 1 <= len(warnings) <= 3                                     # rate limited, not one per frame
    assert_no_escape(rig)
