"""NMEA 0183 heading outputs (docs/marine.md): every sentence read back by an independent parser (pynmeagps)
against the simulator's truth (scipy), checksums, rates, the serial byte budget, withholding while the heading
is unknown, and the transports as bytes on real sockets and a pseudo-terminal."""

from __future__ import annotations

import asyncio
import dataclasses
import math
import os
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
from pynmeagps import NMEAReader
from scipy.spatial.transform import Rotation

from ahrsd.core.estimate import AttitudeEstimate, EstimateFlags, HeadingState
from ahrsd.daemon.config import ConfigError, parse_config
from ahrsd.daemon.nmea_output import NmeaOutput, NmeaOutputs
from ahrsd.daemon.nmea_sentences import MAX_SENTENCE_CHARS, SENTENCE_IDS, build_sentence
from ahrsd.daemon.nmea_transport import SerialTransport, TcpServerTransport, TransportCounters, UdpTransport
from ahrsd.simulation import open_stream
from bench.sim_calibration import save_mag_calibration, sim_chip_mag_model
from support.ahrsd_process import LOW_RATE

RATE_HZ = 819.2
DECLINATION_DEG = -7.3          # a westerly variation, so the sign of HDG's variation field is exercised


def _truth_estimates(seconds: float, stride: int = 8):
    """Estimates built from the simulated turning boat's truth with scipy (not the project's rotation maths),
    plus the truth's heading (°) at every sample for an independent rate of turn."""
    stream = open_stream("boat", rate_hz=RATE_HZ, seed=3, errors="ideal")
    block = stream.next_block(int(seconds * RATE_HZ))
    q = block.truth_q_wxyz
    yaw, pitch, roll = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_euler("ZYX").T
    decl = math.radians(DECLINATION_DEG)
    estimates = []
    for i in range(0, len(block.t_s), stride):
        estimates.append(AttitudeEstimate(
            t_s=float(block.t_s[i]), q_wxyz=q[i], roll_rad=float(roll[i]), pitch_rad=float(pitch[i]),
            yaw_rad=float(yaw[i]), heading_mag_rad=float(yaw[i] - decl) % (2 * math.pi),
            heading_true_rad=float(yaw[i]) % (2 * math.pi), rate_body_rad_s=block.truth_gyro_rad_s[i],
            gyro_bias_rad_s=np.zeros(3), sigma_rpy_rad=np.full(3, 0.001),
            heading_state=HeadingState.GNSS_ONLY))
    return block.t_s, np.degrees(np.unwrap(yaw)), estimates


class ListTransport:
    description = "list"

    def __init__(self):
        self.sent: list[bytes] = []
        self.counters = TransportCounters()

    def open(self, loop):
        pass

    def send(self, data: bytes) -> bool:
        self.sent.append(data)
        return True

    def close(self):
        pass


def _angle_diff_deg(a, b):
    return (a - b + 180.0) % 360.0 - 180.0


@pytest.fixture(scope="module")
def boat():
    return _truth_estimates(60.0)


def test_every_sentence_reads_back_as_the_truth_it_was_built_from(boat):
    t_s, heading_deg, estimates = boat
    transport = ListTransport()
    out = NmeaOutput(transport, "HC", {name: 10.0 for name in SENTENCE_IDS})
    by_time = {}
    for est in estimates:
        before = len(transport.sent)
        out.on_estimate(est)
        for sentence in transport.sent[before:]:
            by_time.setdefault(est.t_s, []).append(sentence)
    assert set(out.sent) == set(SENTENCE_IDS) and min(out.sent.values()) >= 590
    rot_errors, checked = [], set()
    for t, sentences in by_time.items():
        i = int(round(t * RATE_HZ))
        true_heading = heading_deg[i] % 360.0
        for raw in sentences:
            assert len(raw) <= MAX_SENTENCE_CHARS and raw.endswith(b"\r\n")
            msg = NMEAReader.parse(raw, validate=1)             # VALCKSUM: a wrong checksum raises
            assert msg.talker == "HC"
            checked.add(msg.msgID)
            if msg.msgID == "HDT":
                assert abs(_angle_diff_deg(float(msg.headingT), true_heading)) <= 0.051
            elif msg.msgID == "HDG":
                variation = float(msg.variation) * (1 if msg.variationEW == "E" else -1)
                assert variation == pytest.approx(DECLINATION_DEG, abs=0.051)
                assert float(msg.deviation) == 0.0
                assert abs(_angle_diff_deg(float(msg.headingM) + variation, true_heading)) <= 0.11
            elif msg.msgID == "HDM":
                assert abs(_angle_diff_deg(float(msg.headingM) + DECLINATION_DEG, true_heading)) <= 0.11
            elif msg.msgID == "ROT":
                # independent: the truth heading's central difference over ±10 samples, °/min
                k = 10
                if not k <= i < len(t_s) - k:
                    continue
                rate = (heading_deg[i + k] - heading_deg[i - k]) / (t_s[i + k] - t_s[i - k]) * 60.0
                assert msg.valid == "A"
                rot_errors.append(float(msg.rot) - rate)
            elif msg.msgID == "XDR":
                euler = Rotation.from_quat(np.roll(_q_at(estimates, t), -1)).as_euler("ZYX", degrees=True)
                assert (msg.tdrid_01, msg.tdrid_02) == ("PTCH", "ROLL")
                assert (msg.dataunit_01, msg.dataunit_02) == ("D", "D")
                assert float(msg.data_01) == pytest.approx(euler[1], abs=0.051)     # pitch, bow up +
                assert float(msg.data_02) == pytest.approx(euler[2], abs=0.051)     # roll, starboard down +
    assert checked == set(SENTENCE_IDS)
    rot_errors = np.abs(rot_errors)
    # the boat turns at up to tens of °/s; the Earth's rate in the truth gyro is ≈ 0.9 °/min at most
    assert np.max(rot_errors) < 2.0, np.max(rot_errors)
    assert np.any(np.abs([float(NMEAReader.parse(s).rot) for v in by_time.values() for s in v
                          if s[3:6] == b"ROT"]) > 300.0)                           # it did turn


def _q_at(estimates, t):
    for est in estimates:
        if est.t_s == t:
            return est.q_wxyz
    raise KeyError(t)


def test_rate_of_turn_is_negative_turning_to_port():
    est = AttitudeEstimate(t_s=0.0, q_wxyz=np.array([1.0, 0, 0, 0]), roll_rad=0.0, pitch_rad=0.0, yaw_rad=0.0,
                           heading_mag_rad=0.0, heading_true_rad=0.0,
                           rate_body_rad_s=np.array([0.0, 0.0, -math.radians(1.0)]),   # yawing left, 1 °/s
                           gyro_bias_rad_s=np.zeros(3), sigma_rpy_rad=np.zeros(3))
    msg = NMEAReader.parse(build_sentence("ROT", est, "HC"))
    assert float(msg.rot) == pytest.approx(-60.0)


def test_checksums_are_the_xor_of_the_body(boat):
    _, _, estimates = boat
    for name in SENTENCE_IDS:
        raw = build_sentence(name, estimates[100], "IN").decode()
        body, _, checksum = raw.strip().partition("*")
        xor = 0
        for ch in body[1:]:
            xor ^= ord(ch)
        assert checksum == f"{xor:02X}" and body.startswith("$IN" + name)


def test_each_sentence_goes_out_at_its_rate_in_sample_time():
    transport = ListTransport()
    rates = {"HDT": 10.0, "HDG": 10.0, "ROT": 5.0, "XDR": 2.0}
    out = NmeaOutput(transport, "HC", rates)
    base = _truth_estimates(1.0, stride=1)[2][0]
    seconds = 20.0
    for i in range(int(seconds * RATE_HZ)):
        out.on_estimate(dataclasses.replace(base, t_s=i / RATE_HZ))
    for name, hz in rates.items():
        assert abs(out.sent[name] - hz * seconds) <= 1, (name, out.sent[name])
    assert sum(1 for s in transport.sent if s[3:6] == b"HDM") == 0


def test_no_heading_sentence_while_the_heading_is_unknown(boat):
    _, _, estimates = boat
    transport = ListTransport()
    out = NmeaOutput(transport, "HC", {name: 10.0 for name in SENTENCE_IDS})
    for est in estimates[:400]:
        out.on_estimate(dataclasses.replace(est, heading_state=HeadingState.UNKNOWN))
    kinds = {s[3:6].decode() for s in transport.sent}
    assert kinds == {"ROT", "XDR"}
    assert out.withheld["HDT"] > 0 and out.sent["HDT"] == 0
    transport.sent.clear()
    for est in estimates[400:800]:      # initialising: ROT says V, attitude and heading withheld
        out.on_estimate(dataclasses.replace(est, flags=EstimateFlags.INITIALISING))
    assert {s[3:6] for s in transport.sent} == {b"ROT"}
    assert all(NMEAReader.parse(s).valid == "V" for s in transport.sent)
    transport.sent.clear()
    for est in estimates[800:1200]:
        out.on_estimate(est)
    assert {s[3:6].decode() for s in transport.sent} == set(SENTENCE_IDS)


def test_a_4800_baud_port_with_too_many_sentences_is_refused():
    with pytest.raises(ConfigError, match=r"480 bytes/s at 4800 baud.*lower the rates"):
        parse_config({"nmea": [{"url": "serial:/dev/ttyUSB0,4800",
                                "sentences": {"HDT": 10, "HDG": 10, "XDR": 5}}]})
    # HDT 10 Hz (19 B) + HDG 10 Hz (31 B) + ROT 5 Hz (22 B) + XDR 5 Hz (42 B) = 820 B/s fits 38400 baud
    cfg = parse_config({"nmea": [{"url": "serial:/dev/ttyUSB0,38400",
                                  "sentences": {"HDT": 10, "HDG": 10, "ROT": 5, "XDR": 5}}]})
    assert cfg.nmea[0].bytes_per_s() == pytest.approx(820.0)
    slow = parse_config({"nmea": [{"url": "serial:/dev/ttyUSB0"}]}).nmea[0]     # 4800 by default
    assert slow.serial_baud == 4800 and slow.bytes_per_s() <= 480.0
    with pytest.raises(ConfigError, match="talker"):
        parse_config({"nmea": [{"url": "udp:127.0.0.1:10110", "talker": "hc"}]})
    with pytest.raises(ConfigError, match="unknown NMEA sentence"):
        parse_config({"nmea": [{"url": "udp:127.0.0.1:10110", "sentences": {"VTG": 1}}]})
    with pytest.raises(ConfigError, match="tcpserver"):
        parse_config({"nmea": [{"url": "tcp:127.0.0.1:10110"}]})


def test_udp_delivers_one_datagram_per_sentence(boat):
    _, _, estimates = boat
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(5.0)
    transport = UdpTransport(f"udp:127.0.0.1:{rx.getsockname()[1]}")
    out = NmeaOutput(transport, "HC", {"HDT": 10.0})
    for est in estimates[:200]:
        out.on_estimate(est)
    datagrams = [rx.recv(200) for _ in range(out.sent["HDT"])]
    assert len(datagrams) == out.sent["HDT"] >= 19
    assert all(NMEAReader.parse(d, validate=1).msgID == "HDT" for d in datagrams)
    transport.close()
    rx.close()


def test_a_tcp_client_that_stops_reading_does_not_hold_up_another():
    async def scenario():
        transport = TcpServerTransport("tcpserver:127.0.0.1:0")
        transport.open(asyncio.get_running_loop())
        await asyncio.sleep(0.05)
        fast_reader, fast_writer = await asyncio.open_connection("127.0.0.1", transport.port)
        slow = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        slow.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        slow.connect(("127.0.0.1", transport.port))
        for _ in range(100):
            if transport.counters.clients == 2:
                break
            await asyncio.sleep(0.01)
        assert transport.counters.clients == 2
        line = b"$HCHDT,123.4,T*00\r\n"
        received = 0

        async def drain():
            nonlocal received
            while chunk := await fast_reader.read(65536):
                received += len(chunk)

        draining = asyncio.get_running_loop().create_task(drain())
        for _ in range(200):                    # 20000 lines, ≈ 400 kB: far beyond the slow client's buffers
            for _ in range(100):
                transport.send(line)
            await asyncio.sleep(0.002)
        deadline = asyncio.get_running_loop().time() + 20.0
        while received < 20000 * len(line) and asyncio.get_running_loop().time() < deadline:
            await asyncio.sleep(0.01)
        draining.cancel()
        assert received == 20000 * len(line)    # the reading client got every sentence
        assert transport.counters.dropped > 0   # the one that stopped reading lost some, counted
        slow.close()
        fast_writer.close()
        transport.close()

    asyncio.run(scenario())


def test_serial_output_through_a_pseudo_terminal(boat):
    _, _, estimates = boat
    master, slave = os.openpty()
    try:
        transport = SerialTransport(f"serial:{os.ttyname(slave)},38400")
        out = NmeaOutput(transport, "HC", {"HDT": 10.0, "XDR": 5.0})
        for est in estimates[:400]:
            out.on_estimate(est)
        time.sleep(0.2)
        data = b""
        os.set_blocking(master, False)
        try:
            while True:
                data += os.read(master, 4096)
        except BlockingIOError:
            pass
        lines = [ln + b"\n" for ln in data.split(b"\n") if ln]
        assert len(lines) == out.sent["HDT"] + out.sent["XDR"] >= 55
        assert {NMEAReader.parse(ln, validate=1).msgID for ln in lines} == {"HDT", "XDR"}
        transport.close()
    finally:
        os.close(master)
        os.close(slave)


def test_nmea_outputs_part_opens_every_configured_output(tmp_path):
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    cfg = parse_config({"nmea": [{"url": "udp:127.0.0.1:9"}, {"url": f"tcpserver:127.0.0.1:{port}", "talker": "IN"}]})

    async def scenario():
        outputs = NmeaOutputs(cfg.nmea)
        outputs.open(asyncio.get_running_loop())
        await asyncio.sleep(0.05)
        assert [o.talker for o in outputs.outputs] == ["HC", "IN"]
        assert set(outputs.counters()) == {"udp:127.0.0.1:9", f"tcpserver:127.0.0.1:{port}"}
        with socket.create_connection(("127.0.0.1", port), timeout=5):
            pass                                # it listens
        outputs.close()

    asyncio.run(scenario())


@pytest.mark.slow
def test_the_daemon_sends_nmea_from_the_simulated_chip(tmp_path):
    """`ahrsd run --sim level-turns --nmea udp:…`: sentences on a UDP socket; heading sentences only once the
    daemon publishes a heading (on the calibration of the simulated boat's iron: without it and GNSS the heading
    is unknown and only ROT and XDR flow); no sentence ever fails its checksum."""
    save_mag_calibration(tmp_path, sim_chip_mag_model("level-turns"))
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(180.0)
    proc = subprocess.Popen(
        [sys.executable, "-m", "ahrsd.cli", "run", "--sim", "level-turns", *LOW_RATE, "--no-log", "--status-line", "off",
         "--state-dir", str(tmp_path), "--mavlink", "udpout:127.0.0.1:9",
         "--nmea", f"udp:127.0.0.1:{rx.getsockname()[1]}"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        kinds: dict[str, int] = {}
        first = None
        while sum(kinds.values()) < 150:          # 5 s of the default 30 sentences a second
            msg = NMEAReader.parse(rx.recv(200), validate=1)
            first = first or msg.msgID
            kinds[msg.msgID] = kinds.get(msg.msgID, 0) + 1
        assert first == "ROT"                               # initialising: rate only, status V
        assert {"HDT", "HDG", "ROT", "XDR"} <= set(kinds)
        # default rates 10:10:5:5
        assert kinds["HDT"] == pytest.approx(2 * kinds["XDR"], rel=0.25)
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
        rx.close()
