"""Security: MAVLink 2 signing policy on the real receive path (in-process daemon), the persisted signing
timestamp, secret keys never logged, and the systemd unit's exposure score.

Extends tests/test_integration_tools.py::test_notify_watchdog_and_signing (unsigned refusal end to end) with:
wrongly signed and replayed frames, parameter writes, the SYS_STATUS counters, and the timestamp across restarts.
"""

from __future__ import annotations

import logging
import re
import shutil
import subprocess
import time
from pathlib import Path

import pytest

from ahrsd.daemon.config import SigningConfig
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.signing import ONE_MINUTE, initial_timestamp, read_timestamp
from service_rig import gcs_socket, start_service, stop_service
from support.mavlink_feed import drain, feed

REPO = Path(__file__).resolve().parents[1]
KEY = bytes(range(7, 39))                 # 32 bytes
OTHER_KEY = bytes(range(100, 132))
OUR_SYS, OUR_COMP = 1, 200


class _All(logging.Handler):
    def __init__(self):
        super().__init__(logging.DEBUG)
        self.text: list[str] = []

    def emit(self, record):
        self.text.append(self.format(record))


@pytest.fixture
def signed_rig(tmp_path):
    key_file = tmp_path / "signing.key"
    key_file.write_text(KEY.hex() + "\n")
    gcs = gcs_socket()
    logs = _All()
    root = logging.getLogger()
    old_level = root.level
    root.addHandler(logs)
    root.setLevel(logging.DEBUG)
    service, loop = start_service(gcs, tmp_path / "state", signing=SigningConfig(key_file=str(key_file)))
    rig = type("Rig", (), {})()
    rig.service, rig.loop, rig.gcs, rig.logs, rig.ep = service, loop, gcs, logs, service.endpoints[0]
    rig.state_dir = tmp_path / "state"
    yield rig
    stop_service(service, loop)
    gcs.close()
    root.removeHandler(logs)
    root.setLevel(old_level)


def sender(key: bytes | None, timestamp: int | None = None):
    mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    if key is not None:
        mav.signing.secret_key = key
        mav.signing.sign_outgoing = True
        mav.signing.link_id = 1
        mav.signing.timestamp = timestamp or int((time.time() - 1420070400) * 100_000)
    return mav


def param_set(mav, name: bytes, value: float) -> bytes:
    return bytes(mav.param_set_encode(OUR_SYS, OUR_COMP, name, value, 9).pack(mav))


def test_unsigned_and_wrongly_signed_writes_are_refused_and_counted(signed_rig):
    r = signed_rig
    s = r.service
    before = s.params.get("SR_ATTITUDE")
    drain(r)
    feed(r, param_set(sender(None), b"SR_ATTITUDE", 20.0))                       # unsigned
    answers = [m for m in drain(r) if m.get_type() == "PARAM_VALUE"]
    assert answers and answers[-1].param_value == before                          # answered with the value in force
    assert s.params.get("SR_ATTITUDE") == before and s.counters.unsigned_refused == 1
    # signed with another key: the signature fails, so it counts as unsigned (pymavlink hands it over unsigned
    # because read-only traffic must pass): refused and counted the same way
    feed(r, param_set(sender(OTHER_KEY), b"SR_ATTITUDE", 21.0))
    assert s.params.get("SR_ATTITUDE") == before and s.counters.unsigned_refused == 2
    cmd = mavlink.MAV_CMD_SET_MESSAGE_INTERVAL
    for key in (None, OTHER_KEY):                                                 # state-changing commands
        mav = sender(key)
        feed(r, bytes(mav.command_long_encode(OUR_SYS, OUR_COMP, cmd, 0, 30, 1e6, 0, 0, 0, 0, 0).pack(mav)))
        acks = [m for m in drain(r) if m.get_type() == "COMMAND_ACK" and m.command == cmd]
        assert acks and acks[-1].result == mavlink.MAV_RESULT_DENIED
    assert s.commands.counters.unsigned_refused == 2
    assert s.endpoints[0].schedule.rate_hz(mavlink.MAVLINK_MSG_ID_ATTITUDE) == before          # the interval did not change
    status = s.sys_status_message(time.monotonic())
    assert status.errors_count1 == 4                                              # refused writes and commands
    # read-only requests stay accepted unsigned
    feed(r, bytes(sender(None).param_request_read_encode(OUR_SYS, OUR_COMP, b"", 0).pack(sender(None))))
    assert any(m.get_type() == "PARAM_VALUE" for m in drain(r))


def test_correctly_signed_write_applies_and_a_replay_does_not(signed_rig):
    r = signed_rig
    s = r.service
    good = sender(KEY)
    first = param_set(good, b"SR_ATTITUDE", 20.0)
    second = param_set(good, b"SR_ATTITUDE", 25.0)
    feed(r, first)
    assert s.params.get("SR_ATTITUDE") == 20.0
    feed(r, second)
    assert s.params.get("SR_ATTITUDE") == 25.0
    refused = s.counters.unsigned_refused
    feed(r, first)                                                                # replayed: old timestamp
    assert s.params.get("SR_ATTITUDE") == 25.0 and s.counters.unsigned_refused == refused + 1
    old = sender(KEY, timestamp=1000)                                             # a stale signing clock
    feed(r, param_set(old, b"SR_ATTITUDE", 30.0))
    assert s.params.get("SR_ATTITUDE") == 25.0


def test_key_never_logged_and_timestamp_persisted(signed_rig):
    r = signed_rig
    feed(r, param_set(sender(OTHER_KEY), b"SR_ATTITUDE", 21.0))
    feed(r, param_set(sender(None), b"SR_ATTITUDE", 21.0))
    r.service.shutdown_io("test")
    text = "\n".join(r.logs.text)
    assert "MAVLink signing on" in text
    for secret in (KEY.hex(), KEY.hex().upper(), repr(KEY), KEY.hex()[:16]):
        assert secret not in text
    stored = read_timestamp(r.state_dir)
    now_ts = int((time.time() - 1420070400) * 100_000)
    assert stored >= now_ts - 100_000 * 60                                        # saved on shutdown
    # the next run starts after the stored timestamp even if the wall clock went back (no RTC)
    (r.state_dir / "signing_timestamp").write_text(str(now_ts + 10 * ONE_MINUTE))
    assert initial_timestamp(r.state_dir) >= now_ts + 11 * ONE_MINUTE


def test_wall_clock_stepping_back_does_not_reuse_signing_timestamps(signed_rig, monkeypatch):
    r = signed_rig
    ts = []
    for step in (0.0, -3600.0, -86400.0):
        monkeypatch.setattr(time, "time", lambda step=step, real=time.time: real() + step)
        r.service.send(mavlink.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3))
        ts.append(r.ep.signing_timestamp())
    assert ts == sorted(ts) and len(set(ts)) == 3


# ------------------------------------------------------------------------------------------ systemd

EXPOSURE_TARGET = 2.0


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze not available")
def test_systemd_unit_exposure_score_and_device_access():
    unit = REPO / "systemd" / "ahrsd.service"
    r = subprocess.run(["systemd-analyze", "security", "--offline=true", str(unit)], capture_output=True,
                       text=True, timeout=60)
    m = re.search(r"Overall exposure level for ahrsd\.service: ([0-9.]+)", r.stdout + r.stderr)
    assert m, r.stdout[-2000:] + r.stderr[-2000:]
    score = float(m.group(1))
    print(f"systemd-analyze security exposure: {score}")
    assert score <= EXPOSURE_TARGET
    text = unit.read_text()
    assert "DeviceAllow=/dev/spidev0.0 rw" in text                               # still reaches the IMU ...
    assert re.search(r"DeviceAllow=char-tty\w+ rw", text)                         # ... and the serial ports
    assert "SupplementaryGroups=spi dialout" in text
    assert "PrivateDevices=yes" not in text and "PrivateNetwork=yes" not in text   # would cut SPI / UDP
    assert "IPAddressAllow=localhost" in text


def test_a_forged_frame_with_a_future_timestamp_does_not_lock_out_the_genuine_sender(signed_rig):
    """pymavlink records a frame's timestamp for its stream (link, system, component) before it checks the
    signature: one forged frame with the GCS's ids and a timestamp an hour ahead made every genuine signed frame
    of the GCS a "replay" for the next hour. The signature is now checked first."""
    r = signed_rig
    good = sender(KEY)
    forger = sender(OTHER_KEY, timestamp=good.signing.timestamp + 60 * ONE_MINUTE)   # same ids and link id
    feed(r, param_set(forger, b"SR_ATTITUDE", 5.0))
    assert r.service.params.get("SR_ATTITUDE") != 5.0                       # forged: refused as unsigned
    feed(r, param_set(good, b"SR_ATTITUDE", 20.0))
    assert r.service.params.get("SR_ATTITUDE") == 20.0                      # the genuine sender still gets in
    assert r.ep.conn.mav.signing.timestamp < forger.signing.timestamp       # and ours did not jump ahead
