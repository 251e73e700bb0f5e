"""Structure-aware MAVLink fuzzing of an in-process daemon (tests/service_rig.py) on its real receive path
(Endpoint._parse → InboundDispatch.on_message → command router / parameter protocol / autopilot state).

Frames are CRC-valid MAVLink 2 — unsigned, signed with the daemon's key, with another key, or with a stale
timestamp — built from pymavlink's definitions (tests/support/mavlink_frames.py) for every message type the
daemon handles and a sample of the rest, with hostile field values (NaN, ±inf, ±1e38, the extremes of each
integer type, values outside their enums, char ids of odd lengths without NUL) and payloads cut short.

Properties after every frame:
* it was parsed (CRC-valid: `rx_messages` + 1) — the fuzzing reaches past the CRC;
* nothing escaped: no log record with a traceback, no ERROR, `handler_errors` 0;
* the daemon's state (parameters, output rates, calibration, mag-cal session, signing timestamp and the
  per-stream replay state) changed only through a request that was answered ACCEPTED (a PARAM_SET counts as
  accepted when the PARAM_VALUE answering it carries the value asked for);
* every parameter and output rate stays finite and within its range; the autopilot position stays on Earth.

Budget: CI runs `AHRSD_FUZZ_EXAMPLES` (default 1000) examples on the unsigned rig and two fifths as many on the
signed one (SIGNED_EXAMPLES says why), derandomized (the same frames every run, so a failure replays). Longer runs from the command line, with a seed of your choice:
    AHRSD_FUZZ_EXAMPLES=20000 AHRSD_FUZZ_SEED=7 .venv/bin/python -m pytest -s tests/test_fuzz_mavlink.py
`-s` shows the frames generated per message type (the summary test prints them).
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
import multiprocessing
import os
import time
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

from ahrsd.calibration.models import Calibration, MagModel
from ahrsd.core.sample import make_sample
from ahrsd.daemon.config import Config, SigningConfig
from ahrsd.daemon.mavlink_io import mavlink
from bench.sim_calibration import save_mag_calibration, sim_chip_mag_model
from service_rig import gcs_socket, start_service, stop_service
from support.mavlink_feed import drain, feed
from support.mavlink_frames import (
    FrameLog,
    char_values,
    enum_values,
    float_values,
    frame,
    int_values,
    message_payloads,
    sweep_payloads,
)

OUR_SYS, OUR_COMP = 1, 200
GCS_SYS, GCS_COMP = 255, 190
KEY = bytes(range(40, 72))
OTHER_KEY = bytes(range(140, 172))
EXAMPLES = int(os.environ.get("AHRSD_FUZZ_EXAMPLES", "1000"))
# The signed rig's own claim is the signing state (what each kind of signature may move), which rests on the kind,
# the link id and the timestamp, not on the payload: its frames signed with our key reach the same handlers as the
# unsigned rig's, whose EXAMPLES fuzz them. So it runs two fifths as many (each kind still ~80 times or more).
SIGNED_EXAMPLES = max(1, EXAMPLES * 2 // 5)
SEED = os.environ.get("AHRSD_FUZZ_SEED")


def fuzz_settings(examples: int = EXAMPLES):
    """Derandomized unless AHRSD_FUZZ_SEED is set (then that seed: a different, reproducible run)."""
    s = settings(derandomize=SEED is None, deadline=None, max_examples=examples, database=None,
                 suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture,
                                        HealthCheck.data_too_large])

    def apply(fn):
        fn = s(fn)
        return seed(int(SEED))(fn) if SEED is not None else fn
    return apply


FRAMES = FrameLog()
RIGS_FUZZED: set[bool] = set()     # signing of the rigs fuzzed in this process (pytest-xdist splits the tests)

# ------------------------------------------------------------------------------------------ strategies

HANDLED = ("HEARTBEAT", "GLOBAL_POSITION_INT", "GPS_RAW_INT", "TIMESYNC", "COMMAND_LONG", "COMMAND_INT",
           "PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET")
CLASSES = {cls.msgname if hasattr(cls, "msgname") else cls.name: cls for cls in mavlink.mavlink_map.values()}
OTHERS = sorted(set(CLASSES) - set(HANDLED))
HANDLED_COMMANDS = (mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAV_CMD_GET_MESSAGE_INTERVAL,
                    mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAV_CMD_PREFLIGHT_CALIBRATION,
                    42424, 42425, 42426, 42006)
PARAM_NAMES = (b"SR_ATTITUDE", b"SR_ATT_QUAT", b"SR_VISION_POS", b"SR_HIGHRES_IMU", b"SR_SCALED_IMU",
               b"SR_SYS_STATUS", b"MNT_ROLL_DEG", b"MNT_PITCH_DEG", b"MNT_YAW_DEG", b"DECL_MANUAL", b"DECL_DEG")

TARGET_SYS = st.sampled_from([OUR_SYS] * 6 + [0, 2, 255])          # mostly ours: the handlers are the target
TARGET_COMP = st.sampled_from([OUR_COMP] * 6 + [0, 1, 255])
COMMAND_ID = st.one_of(st.sampled_from(HANDLED_COMMANDS), st.sampled_from(HANDLED_COMMANDS),
                       st.sampled_from(HANDLED_COMMANDS), enum_values("MAV_CMD", "uint16_t"))
# plausible command parameters (message ids, intervals, masks, flags, yaw, a position) among hostile floats
COMMAND_PARAM = st.one_of(st.sampled_from([0.0, 0.0, 1.0, 2.0, -1.0, 30.0, 31.0, 32.0, 148.0, 0.5, 76.0, 20000.0,
                                           1e6, 35.7, 51.4, 214.0, -91.0, 360.0, 361.0]), float_values("float"))
POSITION_E7 = st.one_of(st.sampled_from([0, 357000000, 514000000, 900000000, 900000001, -900000001,
                                         1800000001, 2**31 - 1, -2**31]), int_values("int32_t"))
PARAM_ID = st.one_of(st.sampled_from(PARAM_NAMES + (b"SR_ATTITUDEXXXXX", b"ABCDEFGHIJKLMNOP", b"")),
                     char_values(16))
PARAM_VALUE = st.one_of(st.sampled_from([0.0, 1.0, 5.0, 10.0, 50.0, 0.5, -5.0, 45.0, 90.0, 200.0, 201.0]),
                        float_values("float"))

OVERRIDES = {
    "COMMAND_LONG": dict(target_system=TARGET_SYS, target_component=TARGET_COMP,
                         command=COMMAND_ID,
                         **{f"param{i}": COMMAND_PARAM for i in range(1, 8)}),
    "COMMAND_INT": dict(target_system=TARGET_SYS, target_component=TARGET_COMP,
                        command=COMMAND_ID,
                        x=POSITION_E7, y=POSITION_E7, z=COMMAND_PARAM,
                        **{f"param{i}": COMMAND_PARAM for i in range(1, 5)}),
    "PARAM_SET": dict(target_system=TARGET_SYS, target_component=TARGET_COMP, param_id=PARAM_ID,
                      param_value=PARAM_VALUE),
    "PARAM_REQUEST_READ": dict(target_system=TARGET_SYS, target_component=TARGET_COMP, param_id=PARAM_ID,
                               param_index=st.one_of(st.sampled_from([-1, -1, 0, 10, 11, -2]),
                                                     int_values("int16_t"))),
    "PARAM_REQUEST_LIST": dict(target_system=TARGET_SYS, target_component=TARGET_COMP),
    "GLOBAL_POSITION_INT": dict(lat=POSITION_E7, lon=POSITION_E7),
    "GPS_RAW_INT": dict(lat=POSITION_E7, lon=POSITION_E7,
                        fix_type=st.one_of(st.sampled_from([3, 3, 4, 6, 2]), int_values("uint8_t"))),
}


# a valid request per handled command (param1..7): perturbed one field at a time, so that the fuzzing also
# reaches the ACCEPTED paths and the edges of every range, not only the first refusal
VALID_COMMANDS = {
    mavlink.MAV_CMD_SET_MESSAGE_INTERVAL: (30, 20000, 0, 0, 0, 0, 0),
    mavlink.MAV_CMD_GET_MESSAGE_INTERVAL: (31, 0, 0, 0, 0, 0, 0),
    mavlink.MAV_CMD_REQUEST_MESSAGE: (148, 0, 0, 0, 0, 0, 1),
    mavlink.MAV_CMD_PREFLIGHT_CALIBRATION: (1, 0, 0, 0, 0, 0, 0),
    42424: (0, 0, 0, 0, 0, 0, 0), 42425: (0, 0, 0, 0, 0, 0, 0), 42426: (0, 0, 0, 0, 0, 0, 0),
    42006: (30, 0, 35.7, 51.4, 0, 0, 0),
}


@st.composite
def near_valid_command(draw, command_int: bool) -> dict:
    """Field overrides (as strategies) for a COMMAND_LONG/INT: a valid request with 0–2 fields hostile."""
    cmd = draw(st.sampled_from(sorted(VALID_COMMANDS)))
    params = list(map(float, VALID_COMMANDS[cmd]))
    for _ in range(draw(st.integers(0, 2))):
        params[draw(st.integers(0, 6))] = draw(COMMAND_PARAM)
    fields = {"command": cmd, "target_system": OUR_SYS, "target_component": OUR_COMP}
    if command_int:
        fields.update(param1=params[0], param2=params[1], param3=params[2], param4=params[3], z=params[6],
                      x=draw(st.one_of(st.just(0), POSITION_E7)) if params[4] else 0,
                      y=draw(st.one_of(st.just(0), POSITION_E7)) if params[5] else 0)
    else:
        fields.update({f"param{i + 1}": v for i, v in enumerate(params)})
    return {k: st.just(v) for k, v in fields.items()}


@functools.cache
def _payloads_of(name: str):
    """The payload strategy of a message type with its OVERRIDES, built once."""
    return message_payloads(CLASSES[name], OVERRIDES.get(name))


# built once, not per example (hypothesis validates each new strategy object on its first draw)
MESSAGE_NAME = st.one_of(st.sampled_from(HANDLED), st.sampled_from(HANDLED), st.sampled_from(HANDLED),
                         st.sampled_from(HANDLED), st.sampled_from(OTHERS))
SOURCE = st.sampled_from([(GCS_SYS, GCS_COMP), (GCS_SYS, GCS_COMP), (OUR_SYS, 1), (7, 1), (OUR_SYS, OUR_COMP)])
SIGN_KIND_SIGNING = st.sampled_from(["unsigned", "key", "key", "other_key", "stale"])
SIGN_KIND_UNSIGNED = st.sampled_from(["unsigned", "unsigned", "other_key"])
LINK_ID = st.sampled_from([0, 1, 2, 255])


@st.composite
def hostile_frames(draw, signing: bool):
    """(message type, frame bytes, how it is signed) — a handled type 4 times in 5."""
    name = draw(MESSAGE_NAME)
    cls = CLASSES[name]
    if name in ("COMMAND_LONG", "COMMAND_INT") and draw(st.booleans()):
        overrides = {**OVERRIDES[name], **draw(near_valid_command(name == "COMMAND_INT"))}
        payloads = message_payloads(cls, overrides)
    else:
        payloads = _payloads_of(name)
    _values, payload, cut = draw(payloads)
    src = draw(SOURCE)
    sign_kind = draw(SIGN_KIND_SIGNING if signing else SIGN_KIND_UNSIGNED)
    sign = None
    if sign_kind != "unsigned":
        link_id = draw(LINK_ID)
        now = int((time.time() - 1420070400) * 100_000)
        ts = {"stale": now - 10 * 60 * 100_000}.get(sign_kind, now + draw(st.integers(0, 1000)))
        sign = (OTHER_KEY if sign_kind == "other_key" else KEY, link_id, ts)
    data = frame(cls.id, cls.crc_extra, payload, seq=draw(st.integers(0, 255)), sysid=src[0], compid=src[1],
                 sign=sign)
    return name, data, sign_kind, cut


# ------------------------------------------------------------------------------------------ the rigs


class _Records(logging.Handler):
    def __init__(self):
        super().__init__(logging.DEBUG)
        self.bad: list[str] = []

    def emit(self, record):
        if record.exc_info or record.levelno >= logging.ERROR:
            self.bad.append(self.format(record))


def _make_rig(tmp, signing: bool):
    gcs = gcs_socket(rcvbuf=1 << 22)
    changes = dict(mavlink=dataclasses.replace(Config().mavlink, system_id=OUR_SYS))
    if signing:
        key_file = tmp / "signing.key"
        key_file.write_text(KEY.hex() + "\n")
        changes["signing"] = SigningConfig(key_file=str(key_file))
    # the fit worker process is not what is under test here (a session never gets samples in this rig)
    service, loop = start_service(gcs, tmp / "state", warm_fit_worker=False, **changes)
    records = _Records()
    logging.getLogger().addHandler(records)
    rig = SimpleNamespace(service=service, loop=loop, gcs=gcs, ep=service.endpoints[0], records=records,
                          signing=signing)
    _give_fixed_yaw_samples(service)
    return rig


def _give_fixed_yaw_samples(service):
    """A still, level sensor's recent field in the mag-cal window, so FIXED_MAG_CAL_YAW can run to the end."""
    service.apply_calibration(Calibration.identity().with_sensor("mag", MagModel(np.zeros(3), np.eye(3))),
                              save=False)
    for i in range(50):
        service.magcal.on_sample(make_sample(i * 0.02, np.zeros(3), [0.0, 0.0, -9.81], [20.0, 1.0, 40.0]),
                                 SimpleNamespace(roll_rad=0.0, pitch_rad=0.0, yaw_rad=0.0,
                                                 rate_body_rad_s=np.zeros(3), gyro_bias_rad_s=np.zeros(3)))


def _close_rig(rig):
    logging.getLogger().removeHandler(rig.records)
    stop_service(rig.service, rig.loop)
    rig.gcs.close()


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    r = _make_rig(tmp_path_factory.mktemp("fuzz"), signing=False)
    yield r
    _close_rig(r)


@pytest.fixture(scope="module")
def signed_rig(tmp_path_factory):
    r = _make_rig(tmp_path_factory.mktemp("fuzz_signed"), signing=True)
    yield r
    _close_rig(r)


# ------------------------------------------------------------------------------------------ state and checks


def state(rig) -> dict:
    s = rig.service
    mav = rig.ep.conn.mav
    return {
        "params": tuple(s.params.item(i)[1] for i in range(len(s.params))),
        "rates": tuple(ep.schedule.rate_hz(m) for ep in s.endpoints for m in ep.schedule.ids()),
        "calibration": repr(s.pipeline.calibration.to_dict()),
        "magcal_session": s.magcal.session is not None,
        "signing_timestamp": mav.signing.timestamp if rig.signing else None,
        "signing_streams": dict(mav.signing.stream_timestamps) if rig.signing else None,
    }


def check_ranges(rig) -> None:
    s = rig.service
    for i in range(len(s.params)):
        name, value = s.params.item(i)
        spec = s.params.specs[i]
        assert math.isfinite(value) and spec.lo <= value <= spec.hi, (name, value)
    for ep in s.endpoints:
        for mid in ep.schedule.ids():
            hz = ep.schedule.rate_hz(mid)
            assert math.isfinite(hz) and 0.0 <= hz <= ep.schedule.max_rate_hz(mid), (mid, hz)
    ap = s.autopilot
    assert ap.lat_deg is None or (-90 <= ap.lat_deg <= 90 and -180 <= ap.lon_deg <= 180)
    assert math.isfinite(s.declination_rad)
    assert np.all(np.isfinite(s.pipeline.calibration.mag.hard_iron_ut))


def accepted_requests(sent: list, name: str) -> set:
    out = set()
    for m in sent:
        if m.get_type() == "COMMAND_ACK" and m.result in (mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_IN_PROGRESS):
            out.add(("command", m.command))
        elif m.get_type() == "PARAM_VALUE":
            out.add(("param", m.param_id, m.param_value))
    return out


def check_frame(rig, name: str, data: bytes, sign_kind: str) -> None:
    s = rig.service
    before = state(rig)
    rx = rig.ep.counters.rx_messages
    feed(rig, data)
    sent = drain(rig)
    after = state(rig)
    assert rig.ep.counters.rx_messages == rx + 1, f"{name}: a CRC-valid frame was not parsed"
    assert not rig.records.bad, rig.records.bad[:2]
    assert s.commands.counters.handler_errors == 0
    check_ranges(rig)
    accepted = accepted_requests(sent, name)
    for m in sent:
        if m.get_type() == "COMMAND_ACK":
            FRAMES.acks[(m.command, mavlink.enums["MAV_RESULT"][m.result].name[len("MAV_RESULT_"):])] += 1
    sent_signed = len(sent)
    for key in ("params", "rates", "calibration", "magcal_session"):
        if after[key] != before[key]:
            assert any(a[0] == "command" for a in accepted) or any(a[0] == "param" for a in accepted), (
                f"{name}: {key} changed without an ACCEPTED answer")
    if after["params"] != before["params"]:
        changed = [i for i, (a, b) in enumerate(zip(before["params"], after["params"])) if a != b]
        for i in changed:
            pname, value = s.params.item(i)
            assert ("param", pname, value) in accepted, f"{pname} changed to {value} without a PARAM_VALUE of it"
    if rig.signing and sign_kind != "key":
        # only a frame signed with our key may move the signing state; our own sends add 1 each
        assert after["signing_streams"] == before["signing_streams"], f"{name} ({sign_kind}) moved a stream"
        assert before["signing_timestamp"] <= after["signing_timestamp"] <= before["signing_timestamp"] + sent_signed


# ------------------------------------------------------------------------------------------ the fuzz tests


def fuzz_one(rig, generated) -> None:
    name, data, sign_kind, cut = generated
    RIGS_FUZZED.add(rig.signing)
    FRAMES.by_type[name] += 1
    FRAMES.signed[sign_kind] += 1
    FRAMES.truncated += cut
    check_frame(rig, name, data, sign_kind)


@fuzz_settings()
@given(hostile_frames(signing=False))
def test_hostile_frames_unsigned(rig, generated):
    fuzz_one(rig, generated)


@fuzz_settings(SIGNED_EXAMPLES)
@given(hostile_frames(signing=True))
def test_hostile_frames_signed(signed_rig, generated):
    fuzz_one(signed_rig, generated)


def test_fuzz_summary_every_handled_type_and_signing_case_was_generated(rig, signed_rig):
    print("\n" + FRAMES.summary())
    print("COMMAND_ACKs (command, result): " + ", ".join(f"{c}/{r}: {n}" for (c, r), n in sorted(FRAMES.acks.items())))
    print(f"commands refused {rig.service.commands.counters.refused} + "
          f"{signed_rig.service.commands.counters.refused}, parameter writes refused "
          f"{rig.service.params.rejected_writes} + {signed_rig.service.params.rejected_writes}, "
          f"autopilot positions refused {rig.service.autopilot.rejected_positions} + "
          f"{signed_rig.service.autopilot.rejected_positions}")
    if RIGS_FUZZED != {False, True}:
        pytest.skip("run together with both fuzz tests")
    assert all(FRAMES.by_type[n] >= 10 for n in HANDLED), FRAMES.by_type
    assert len(set(FRAMES.by_type) - set(HANDLED)) >= 20
    assert set(FRAMES.signed) == {"unsigned", "key", "other_key", "stale"}
    assert FRAMES.truncated > 0
    assert rig.service.commands.counters.refused > 0 and rig.service.params.rejected_writes > 0
    assert rig.service.autopilot.rejected_positions > 0


def sweep_frames(seq0: int = 0):
    """Every message of the dialect at its extremes (addressed to us), then every handled command with all
    parameters NaN / ±inf / ±1e38 and COMMAND_INT x/y at the int32 extremes."""
    out = []
    for name, cls, payload in sweep_payloads({"target_system": OUR_SYS, "target_component": OUR_COMP}):
        out.append((name, frame(cls.id, cls.crc_extra, payload, seq=seq0 + len(out), sysid=GCS_SYS,
                                compid=GCS_COMP)))
    mav = mavlink.MAVLink(None, srcSystem=GCS_SYS, srcComponent=GCS_COMP)
    for cmd in HANDLED_COMMANDS:
        for v in (math.nan, math.inf, -math.inf, 1e38, -1e38):
            out.append(("COMMAND_LONG", mav.command_long_encode(OUR_SYS, OUR_COMP, cmd, 0, *[v] * 7).pack(mav)))
            for x, y in ((2**31 - 1, -2**31), (-2**31, 2**31 - 1)):
                out.append(("COMMAND_INT", mav.command_int_encode(OUR_SYS, OUR_COMP, 0, cmd, 0, 0, *[v] * 4, x, y,
                                                                  v).pack(mav)))
    return out


def test_every_message_type_at_its_extremes(rig):
    """All 300 message types of the dialect with every field at its maximum, at its minimum, cut to one byte;
    then the handled commands with non-finite and huge parameters: the same properties as the fuzz tests."""
    frames_ = sweep_frames()
    for name, data in frames_:
        check_frame(rig, name, data, "unsigned")
    refused = rig.service.commands.counters.refused
    print(f"\nsweep: {len(frames_)} frames of {len({n for n, _ in frames_})} message types; commands refused "
          f"so far {refused}")
    assert refused >= 5 * len(HANDLED_COMMANDS) // 2


def test_outputs_keep_flowing_under_hostile_frames(tmp_path):
    """The whole daemon in-process (simulated chip, reader, publishers, housekeeping) while the sweep's
    hostile frames arrive at ~1000 per second: no frame changes or turns off an output's rate, and every
    default output keeps flowing. The window opens once the heading is trusted (the estimator initialised: a
    loaded machine takes longer to start). Counted on the daemon's own wakes, not on the wall clock: a reader
    wake sends each output that fell due at most once (daemon/outputs.py), so a daemon starved of CPU (a loaded
    2-core machine) wakes, and sends, less; each output must go out, or be counted held by the daemon (withheld:
    VISION_POSITION_ESTIMATE while the heading is not trusted; unchanged: no new estimate since the last one),
    at least half as often as it fell due or the daemon woke, whichever is fewer. And nothing is lost uncounted:
    every deadline the schedule served in the window arrived or was counted held. The exact rates under a
    flood are bench/soak.py's job."""
    import asyncio
    from collections import Counter

    from ahrsd.daemon.config import EndpointConfig, StateConfig
    from ahrsd.daemon.service import Service

    gcs = gcs_socket(rcvbuf=1 << 23)
    cfg = dataclasses.replace(Config(), endpoints=(EndpointConfig(f"udpout:127.0.0.1:{gcs.getsockname()[1]}"),),
                              state=StateConfig(str(tmp_path / "state")),
                              mavlink=dataclasses.replace(Config().mavlink, system_id=OUR_SYS))
    save_mag_calibration(tmp_path / "state", sim_chip_mag_model())      # no heading is sent on an uncalibrated one
    service = Service(cfg)
    records = _Records()
    logging.getLogger().addHandler(records)
    frames_ = [data for _name, data in sweep_frames()]
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    window_s, counts = 4.0, Counter()

    def read_gcs(into):
        while True:
            try:
                data = gcs.recv(65536)
            except BlockingIOError:
                return
            for m in parser.parse_buffer(data) or ():
                into[m.get_type()] += 1

    def slots():
        s = service.endpoints[0].schedule
        return s.served_slots(), s.withheld_slots(), s.unchanged_slots()

    async def scenario():
        run = asyncio.create_task(service.run())
        t_start = time.monotonic()                  # start-up and the estimator's initialisation
        while not service.heading_trusted(time.monotonic()) and time.monotonic() - t_start < 120.0:
            await asyncio.sleep(0.05)
        read_gcs(Counter())
        slots0 = slots()
        wakes0 = service.counters.wakes
        t0, i = time.monotonic(), 0
        while time.monotonic() - t0 < window_s:
            ep = service.endpoints[0]
            for _ in range(5):
                ep._parse(frames_[i % len(frames_)])
                ep._end_of_datagram()
                i += 1
            read_gcs(counts)
            await asyncio.sleep(0.005)
        elapsed = time.monotonic() - t0
        wakes = service.counters.wakes - wakes0
        slots1 = slots()
        read_gcs(counts)
        ep = service.endpoints[0]
        rates_after = {mid: ep.schedule.rate_hz(mid) for mid in ep.schedule.ids()}
        service.request_stop(0)
        held = [{mid: b[mid] - a[mid] for mid in b} for a, b in zip(slots0, slots1)]   # served, withheld, unchanged
        return await run, i, elapsed, wakes, rates_after, held

    try:
        exit_code, fed, elapsed, wakes, rates_after, (served, withheld, unchanged) = asyncio.run(scenario())
    finally:
        logging.getLogger().removeHandler(records)
        gcs.close()
    from ahrsd.daemon.output_registry import OUTPUTS

    nominal = {mavlink.mavlink_map[o.message_id].msgname: o.default_hz for o in OUTPUTS if o.default_hz > 0}
    nominal["HEARTBEAT"] = 1.0
    rates = {n: counts[n] / elapsed for n in nominal}
    ids = {mavlink.mavlink_map[o.message_id].msgname: o.message_id for o in OUTPUTS}
    print(f"\n{fed} hostile frames in {elapsed:.1f} s, {wakes} reader wakes; output rates, Hz: "
          + ", ".join(f"{n} {r:.1f}" for n, r in rates.items()) + "; served / withheld / unchanged: "
          + ", ".join(f"{n} {served[ids[n]]}/{withheld[ids[n]]}/{unchanged[ids[n]]}" for n in nominal if n in ids))
    assert exit_code == 0 and not records.bad, records.bad[:2]
    assert service.commands.counters.handler_errors == 0
    # no hostile frame (NaN/negative SET_MESSAGE_INTERVAL, hostile PARAM_SET of an SR_ rate) moved a rate
    assert rates_after == {o.message_id: o.default_hz for o in OUTPUTS}, rates_after
    for name, hz in nominal.items():
        # HEARTBEAT is housekeeping's (1 Hz tick), the others go out on reader wakes (at most one each per wake)
        if name == "HEARTBEAT":
            assert counts[name] >= int(0.5 * hz * elapsed), (name, counts[name], rates[name])
            continue
        mid = ids[name]
        held = withheld[mid] + unchanged[mid]
        assert counts[name] + held >= int(0.5 * min(hz * elapsed, wakes)), (name, counts[name], held, wakes)
        # every deadline served went out or was counted held: none lost uncounted, none sent twice
        assert counts[name] + held == served[mid], (name, counts[name], withheld[mid], unchanged[mid], served[mid])


# ------------------------------------------------------------------------------------------ bytes and damage


def _valid_frames():
    s = mavlink.MAVLink(None, srcSystem=GCS_SYS, srcComponent=GCS_COMP)
    return [s.param_request_read_encode(OUR_SYS, OUR_COMP, b"SR_ATTITUDE", -1).pack(s),
            s.command_long_encode(OUR_SYS, OUR_COMP, 510, 0, 30, 0, 0, 0, 0, 0, 0).pack(s),
            s.timesync_encode(0, 12345).pack(s),
            s.heartbeat_encode(6, 8, 0, 0, 4).pack(s)]


def _rx_total(rig) -> int:
    c = rig.ep.counters
    return c.rx_messages + c.rx_malformed + c.rx_unknown + c.rx_bad_signature


@fuzz_settings(examples=max(100, EXAMPLES // 3))
@given(st.binary(min_size=1, max_size=600))
def test_random_bytes_are_counted_never_raised(rig, data):
    """Any non-empty datagram is accounted for: parsed, or counted malformed/unknown/badly signed."""
    before = _rx_total(rig)
    feed(rig, data)
    drain(rig)
    assert _rx_total(rig) > before
    assert not rig.records.bad and rig.service.commands.counters.handler_errors == 0
    check_ranges(rig)


@fuzz_settings(examples=max(100, EXAMPLES // 3))
@given(st.integers(0, 3), st.integers(1, 300), st.integers(0, 255), st.integers(0, 7), st.sampled_from(
    ["truncate", "flip", "oversize", "length_byte", "append_junk"]))
def test_damaged_frames_are_rejected_and_counted(rig, which, pos, value, bit, how):
    good = bytes(_valid_frames()[which])
    frame_ = bytearray(good)
    n = len(frame_)
    if how == "truncate":
        data = bytes(frame_[: 1 + pos % (n - 1)])
    elif how == "flip":
        frame_[pos % n] ^= 1 << bit
        data = bytes(frame_)
    elif how == "oversize":
        data = good + bytes([value]) * pos
    elif how == "length_byte":
        frame_[1] = value
        data = bytes(frame_)
    else:
        data = good + bytes([0xFD, value, 0, 0, 1, 255, 190]) + bytes(pos % 20)
    malformed = rig.ep.counters.rx_malformed + rig.ep.counters.rx_unknown
    rx = rig.ep.counters.rx_messages
    feed(rig, data)
    drain(rig)
    if data != good:
        # a damaged frame is never delivered as itself: either counted bad, or (a flip that happens to keep
        # a valid CRC is impossible for one bit under X.25) nothing else than the intact prefix got through
        assert rig.ep.counters.rx_malformed + rig.ep.counters.rx_unknown > malformed or (
            how in ("oversize", "append_junk") and rig.ep.counters.rx_messages == rx + 1)
    assert not rig.records.bad
    check_ranges(rig)


def test_bad_crc_truncated_and_junk_each_count_and_a_good_frame_still_passes(rig):
    good = _valid_frames()[0]
    bad_crc = bytearray(good)
    bad_crc[-1] ^= 0xFF
    c0 = rig.ep.counters.rx_malformed
    for data in (bytes(bad_crc), good[:9], b"\x55" * 100):
        feed(rig, data)
    assert rig.ep.counters.rx_malformed - c0 == 3
    still_answers(rig)


def still_answers(rig) -> None:
    drain(rig)
    s = mavlink.MAVLink(None, srcSystem=GCS_SYS, srcComponent=GCS_COMP)
    feed(rig, s.param_request_read_encode(OUR_SYS, OUR_COMP, b"", 0).pack(s))
    got = [m for m in drain(rig) if m.get_type() == "PARAM_VALUE"]
    assert got and got[0].param_index == 0


def test_still_answers_after_the_hostile_examples(rig, signed_rig):
    still_answers(rig)
    still_answers(signed_rig)
    assert not rig.records.bad and not signed_rig.records.bad


def test_flood_of_commands_and_parameter_requests_is_answered(rig):
    """2000 GET_MESSAGE_INTERVALs and 2000 PARAM_REQUEST_READs back to back: each one answered."""
    drain(rig)
    acks = values = 0
    s = mavlink.MAVLink(None, srcSystem=GCS_SYS, srcComponent=GCS_COMP)
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
    check_ranges(rig)


def _start_mag_cal(rig) -> None:
    s = mavlink.MAVLink(None, srcSystem=GCS_SYS, srcComponent=GCS_COMP)
    feed(rig, s.command_long_encode(OUR_SYS, OUR_COMP, 42424, 0, 0, 0, 0, 0, 0, 0, 0).pack(s))   # DO_START_MAG_CAL
    drain(rig)


def _cancel_mag_cal(rig) -> None:
    s = mavlink.MAVLink(None, srcSystem=GCS_SYS, srcComponent=GCS_COMP)
    feed(rig, s.command_long_encode(OUR_SYS, OUR_COMP, 42426, 0, 0, 0, 0, 0, 0, 0, 0).pack(s))   # DO_CANCEL_MAG_CAL
    drain(rig)


def test_the_rig_runs_a_mag_cal_session_without_starting_a_fit_worker(tmp_path):
    """The fuzz rig's service is built with warm_fit_worker=False: a session starts (the fuzz reaches its
    handlers) and no worker process is spawned for fits it never gets samples for. (A rig of its own: the
    fuzz's rig may have seen the same command within the duplicate window.)"""
    rig = _make_rig(tmp_path, signing=False)
    before = set(multiprocessing.active_children())
    try:
        _start_mag_cal(rig)
        assert rig.service.magcal.calibrating
        assert set(multiprocessing.active_children()) == before
        _cancel_mag_cal(rig)
        assert not rig.service.magcal.calibrating
    finally:
        _close_rig(rig)


def test_by_default_a_mag_cal_start_warms_the_fit_worker(tmp_path):
    """The daemon's default: the fit worker process starts with the session (its imports done while the operator
    turns), before any fit."""
    gcs = gcs_socket(rcvbuf=1 << 22)
    service, loop = start_service(gcs, tmp_path / "state", mavlink=dataclasses.replace(Config().mavlink,
                                                                                          system_id=OUR_SYS))
    rig = SimpleNamespace(service=service, loop=loop, gcs=gcs, ep=service.endpoints[0], signing=False)
    before = set(multiprocessing.active_children())
    try:
        _start_mag_cal(rig)
        assert service.magcal.calibrating
        assert len(set(multiprocessing.active_children()) - before) == 1
    finally:
        _cancel_mag_cal(rig)
        stop_service(service, loop)
        gcs.close()
