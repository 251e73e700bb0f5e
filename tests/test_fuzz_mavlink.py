"""MAVLink input fuzzing at unit level: the real receive path (Endpoint._parse → Service._on_message → command
router / parameter protocol) of an in-process daemon, fed hostile bytes and hostile field values.

Hypothesis with derandomize=True: the examples are a fixed function of the test, so a failure replays. The
end-to-end flood against the daemon subprocess is in test_reliability_daemon.py; the long one in bench/soak.py.
Invariants after every example: nothing raised, no handler error logged or counted, every parameter finite and
in its range, every output rate legal, and a valid request is still answered.
"""

from __future__ import annotations

import asyncio
import logging
import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ahrsd.daemon.mavlink_io import mavlink
from service_rig import gcs_socket, start_service, stop_service

FUZZ = settings(derandomize=True, deadline=None, max_examples=300,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
OUR_SYS, OUR_COMP = 1, 200


class _Errors(logging.Handler):
    def __init__(self):
        super().__init__(logging.ERROR)
        self.records: list[logging.LogRecord] = []

    def emit(self, record):
        self.records.append(record)




@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    """A started Service (no reader task) whose only endpoint sends to `gcs`, a UDP socket we read."""
    tmp = tmp_path_factory.mktemp("fuzz")
    gcs = gcs_socket(rcvbuf=1 << 22)
    service, loop = start_service(gcs, tmp / "state")
    errors = _Errors()
    logging.getLogger("ahrsd").addHandler(errors)
    rig = type("Rig", (), {})()
    rig.service, rig.loop, rig.gcs, rig.errors = service, loop, gcs, errors
    rig.ep = service.endpoints[0]
    rig.sender = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    rig.sender.robust_parsing = True
    yield rig
    stop_service(service, loop)
    gcs.close()
    logging.getLogger("ahrsd").removeHandler(errors)


def drain(rig) -> list:
    """Run pending loop callbacks, then every message the daemon sent to the GCS socket."""
    rig.loop.run_until_complete(asyncio.sleep(0))
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    out = []
    while True:
        try:
            data = rig.gcs.recv(65536)
        except BlockingIOError:
            return out
        out += [m for m in parser.parse_buffer(data) or () if m.get_type() != "BAD_DATA"]


def feed(rig, data: bytes) -> None:
    """One datagram through the endpoint's parser and dispatch, as the event loop would deliver it."""
    rig.ep._parse(data)
    rig.ep._end_of_datagram()


def check_invariants(rig) -> None:
    s = rig.service
    assert not rig.errors.records, [r.getMessage() for r in rig.errors.records[:3]]
    assert s.commands.counters.handler_errors == 0
    for i in range(len(s.params)):
        name, value = s.params.item(i)
        spec = s.params.specs[i]
        assert math.isfinite(value) and spec.lo <= value <= spec.hi, (name, value)
    for ep in s.endpoints:
        for mid in ep.schedule.ids():
            hz = ep.schedule.rate_hz(mid)
            assert math.isfinite(hz) and 0.0 <= hz <= ep.schedule.max_rate_hz(mid), (mid, hz)


def still_answers(rig) -> None:
    drain(rig)
    feed(rig, rig.sender.param_request_read_encode(OUR_SYS, OUR_COMP, b"", 0).pack(rig.sender))
    got = [m for m in drain(rig) if m.get_type() == "PARAM_VALUE"]
    assert got and got[0].param_index == 0


# ------------------------------------------------------------------------------------------ bytes


@FUZZ
@given(st.binary(min_size=0, max_size=600))
def test_random_bytes_are_counted_never_raised(rig, data):
    before = rig.ep.counters.rx_malformed
    feed(rig, data)
    assert rig.ep.counters.rx_malformed >= before
    check_invariants(rig)


def _valid_frames(rig):
    s = rig.sender
    return [s.param_request_read_encode(OUR_SYS, OUR_COMP, b"SR_ATTITUDE", -1).pack(s),
            s.command_long_encode(OUR_SYS, OUR_COMP, 510, 0, 30, 0, 0, 0, 0, 0, 0).pack(s),
            s.timesync_encode(0, 12345).pack(s),
            s.heartbeat_encode(6, 8, 0, 0, 4).pack(s)]


@FUZZ
@given(st.integers(0, 3), st.integers(1, 300), st.integers(0, 255), st.integers(0, 7), st.sampled_from(
    ["truncate", "flip", "oversize", "length_byte", "append_junk"]))
def test_damaged_frames_are_rejected_and_counted(rig, which, pos, value, bit, how):
    frame = bytearray(_valid_frames(rig)[which])
    n = len(frame)
    if how == "truncate":
        data = bytes(frame[: 1 + pos % (n - 1)])
    elif how == "flip":
        frame[pos % n] ^= 1 << bit
        data = bytes(frame)
    elif how == "oversize":
        data = bytes(frame) + bytes([value]) * pos
    elif how == "length_byte":
        frame[1] = value
        data = bytes(frame)
    else:
        data = bytes(frame) + bytes([0xFD, value, 0, 0, 1, 255, 190]) + bytes(pos % 20)
    rx0, bad0 = rig.ep.counters.rx_messages, rig.ep.counters.rx_malformed + rig.ep.counters.rx_unknown
    feed(rig, data)
    rx1, bad1 = rig.ep.counters.rx_messages, rig.ep.counters.rx_malformed + rig.ep.counters.rx_unknown
    assert (rx1 - rx0) + (bad1 - bad0) >= 1 or data == bytes(_valid_frames(rig)[which]) or len(data) == 0
    check_invariants(rig)


def test_bad_crc_truncated_and_junk_each_count_and_a_good_frame_still_passes(rig):
    good = _valid_frames(rig)[0]
    bad_crc = bytearray(good)
    bad_crc[-1] ^= 0xFF
    c0 = rig.ep.counters.rx_malformed
    for data in (bytes(bad_crc), good[:9], b"\x55" * 100):
        feed(rig, data)
    assert rig.ep.counters.rx_malformed - c0 == 3
    still_answers(rig)


# ------------------------------------------------------------------------------------------ hostile field values

HOSTILE_FLOAT = st.one_of(st.sampled_from([math.nan, math.inf, -math.inf, 0.0, -0.0, 1e38, -1e38, 3.4e38, 1e-45]),
                          st.floats(width=32, allow_nan=True, allow_infinity=True))
TARGET_SYS = st.sampled_from([0, OUR_SYS, 2, 255])
TARGET_COMP = st.sampled_from([0, OUR_COMP, 1, 255])
COMMANDS = st.one_of(st.sampled_from([510, 511, 512, 241, 42424, 42425, 42426, 0, 65535, 246, 400]),
                     st.integers(0, 65535))
PARAM_IDS = st.one_of(st.sampled_from([b"SR_ATTITUDE", b"SR_VISION_POS", b"MNT_ROLL_DEG", b"MNT_PITCH_DEG",
                                       b"DECL_MANUAL", b"DECL_DEG", b"Z" * 16, b"SR_ATTITUDEXXXXX", b""]),
                      st.binary(min_size=0, max_size=16))


@st.composite
def hostile_messages(draw):
    kind = draw(st.sampled_from(["command_long", "command_int", "param_set", "param_read", "param_list",
                                 "timesync", "heartbeat", "global_position_int", "gps_raw_int"]))
    s = mavlink  # message constructors
    if kind == "command_long":
        return s.MAVLink_command_long_message(draw(TARGET_SYS), draw(TARGET_COMP), draw(COMMANDS),
                                              draw(st.integers(0, 255)), *[draw(HOSTILE_FLOAT) for _ in range(7)])
    if kind == "command_int":
        return s.MAVLink_command_int_message(draw(TARGET_SYS), draw(TARGET_COMP), draw(st.integers(0, 255)),
                                             draw(COMMANDS), draw(st.integers(0, 255)), draw(st.integers(0, 255)),
                                             *[draw(HOSTILE_FLOAT) for _ in range(4)],
                                             draw(st.integers(-2**31, 2**31 - 1)),
                                             draw(st.integers(-2**31, 2**31 - 1)), draw(HOSTILE_FLOAT))
    if kind == "param_set":
        return s.MAVLink_param_set_message(draw(TARGET_SYS), draw(TARGET_COMP), draw(PARAM_IDS), draw(HOSTILE_FLOAT),
                                           draw(st.integers(0, 255)))
    if kind == "param_read":
        return s.MAVLink_param_request_read_message(draw(TARGET_SYS), draw(TARGET_COMP), draw(PARAM_IDS),
                                                    draw(st.integers(-32768, 32767)))
    if kind == "param_list":
        return s.MAVLink_param_request_list_message(draw(TARGET_SYS), draw(TARGET_COMP))
    if kind == "timesync":
        return s.MAVLink_timesync_message(draw(st.integers(-2**63, 2**63 - 1)), draw(st.integers(-2**63, 2**63 - 1)))
    if kind == "heartbeat":
        return s.MAVLink_heartbeat_message(draw(st.integers(0, 255)), draw(st.integers(0, 255)),
                                           draw(st.integers(0, 255)), draw(st.integers(0, 2**32 - 1)),
                                           draw(st.integers(0, 255)), 3)
    if kind == "global_position_int":
        return s.MAVLink_global_position_int_message(draw(st.integers(0, 2**32 - 1)),
                                                     *[draw(st.integers(-2**31, 2**31 - 1)) for _ in range(4)],
                                                     *[draw(st.integers(-32768, 32767)) for _ in range(3)],
                                                     draw(st.integers(0, 65535)))
    return s.MAVLink_gps_raw_int_message(draw(st.integers(0, 2**64 - 1)), draw(st.integers(0, 255)),
                                         *[draw(st.integers(-2**31, 2**31 - 1)) for _ in range(3)],
                                         *[draw(st.integers(0, 65535)) for _ in range(4)],
                                         draw(st.integers(0, 255)))


@FUZZ
@given(hostile_messages(), st.sampled_from([(255, 190), (1, 1), (7, 1), (1, 200)]))
def test_hostile_field_values_are_handled(rig, msg, src):
    rig.sender.srcSystem, rig.sender.srcComponent = src
    try:
        data = msg.pack(rig.sender)
    finally:
        rig.sender.srcSystem, rig.sender.srcComponent = 255, 190
    feed(rig, data)
    drain(rig)
    check_invariants(rig)
    # the autopilot state never takes a non-finite position
    ap = rig.service.autopilot
    for v in (ap.lat_deg, ap.lon_deg):
        assert v is None or math.isfinite(v)


def test_still_answers_after_the_hostile_examples(rig):
    still_answers(rig)
    check_invariants(rig)


def test_flood_of_commands_and_parameter_requests_is_answered(rig):
    """2000 GET_MESSAGE_INTERVALs and 2000 PARAM_REQUEST_READs back to back: each one answered."""
    drain(rig)
    acks = values = 0
    s = rig.sender
    n_params = len(rig.service.params)
    for i in range(2000):
        feed(rig, s.command_long_encode(OUR_SYS, OUR_COMP, 510, i % 2, 30, 0, 0, 0, 0, 0, 0).pack(s))
        feed(rig, s.param_request_read_encode(OUR_SYS, OUR_COMP, b"", i % n_params).pack(s))
        if i % 100 == 99:
            got = drain(rig)
            acks += sum(1 for m in got if m.get_type() == "COMMAND_ACK")
            values += sum(1 for m in got if m.get_type() == "PARAM_VALUE")
    got = drain(rig)
    acks += sum(1 for m in got if m.get_type() == "COMMAND_ACK")
    values += sum(1 for m in got if m.get_type() == "PARAM_VALUE")
    assert acks == 2000 and values == 2000
    check_invariants(rig)


def test_sixteen_char_unterminated_param_id_round_trips(rig):
    """A 16-character name fills param_id with no NUL: it must be read as 16 characters, not overrun."""
    from ahrsd.daemon.params import decode_param_id

    assert decode_param_id(b"ABCDEFGHIJKLMNOP") == "ABCDEFGHIJKLMNOP"
    drain(rig)
    before = rig.service.params.rejected_writes
    feed(rig, rig.sender.param_set_encode(OUR_SYS, OUR_COMP, b"ABCDEFGHIJKLMNOP", 1.0, 9).pack(rig.sender))
    texts = [m.text for m in drain(rig) if m.get_type() == "STATUSTEXT"]
    assert any("ABCDEFGHIJKLMNOP" in t for t in texts)
    assert rig.service.params.rejected_writes == before + 1
