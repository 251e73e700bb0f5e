"""Per-endpoint outputs: profiles and overrides in the config, each endpoint's own schedule, SET_MESSAGE_INTERVAL
changing only the endpoint it came in on, and what each endpoint really receives from `ahrsd run`.

The expected message sets are written out here from the documented profiles (docs/daemon.md, "Outputs per
endpoint"), not taken from daemon.output_profiles.
"""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ahrsd.daemon.config import ConfigError, EndpointConfig, parse_config
from ahrsd.daemon.mavlink_io import mavlink
from service_rig import start_service_on, stop_process, stop_service
from bench.sim_calibration import save_mag_calibration, sim_chip_mag_model
from support.ahrsd_process import LOW_RATE

ATT, ATTQ, VPE = 30, 31, 102
HIGHRES, SCALED, SYS_STATUS, HEARTBEAT = 105, 26, 1, 0
DEFAULT_HZ = {ATT: 50.0, ATTQ: 10.0, VPE: 30.0, HIGHRES: 10.0, SCALED: 0.0, SYS_STATUS: 1.0}
AUTOPILOT_HZ = {ATT: 0.0, ATTQ: 0.0, VPE: 30.0, HIGHRES: 0.0, SCALED: 0.0, SYS_STATUS: 1.0}
AHRSD = Path(sys.executable).with_name("ahrsd")


def udp_sink() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.setblocking(False)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
    return s


def test_config_profile_and_overrides():
    cfg = parse_config({"endpoint": [
        {"url": "udpout:127.0.0.1:14550"},
        {"url": "/dev/ttyAMA0,57600", "profile": "autopilot", "outputs": {"attitude_hz": 5.0}}]})
    gcs, ap = cfg.endpoints
    assert gcs.profile == "gcs" and gcs.overrides_hz == {} and gcs.serial_baud is None
    assert ap.profile == "autopilot" and ap.overrides_hz == {ATT: 5.0} and ap.serial_baud == 57600
    assert EndpointConfig("/dev/ttyUSB0").serial_baud == 115200
    for bad, word in (({"url": "udpout:1.2.3.4:5", "profile": "fast"}, "profile"),
                      ({"url": "udpout:1.2.3.4:5", "outputs": {"attitude": 5}}, "attitude"),
                      ({"url": "udpout:1.2.3.4:5", "outputs": {"vision_position_estimate_hz": 60}}, "60"),
                      ({"url": "udpout:1.2.3.4:5", "outputs": 5}, "outputs")):
        with pytest.raises(ConfigError, match=word):
            parse_config({"endpoint": [bad]})


def _rates(ep) -> dict[int, float]:
    return {mid: ep.schedule.rate_hz(mid) for mid in DEFAULT_HZ}


def test_each_endpoint_has_its_profile_rates_and_set_message_interval_changes_only_its_own(tmp_path):
    a, b, c = udp_sink(), udp_sink(), udp_sink()
    service, loop = start_service_on([
        EndpointConfig(f"udpout:127.0.0.1:{a.getsockname()[1]}"),
        EndpointConfig(f"udpout:127.0.0.1:{b.getsockname()[1]}", profile="autopilot"),
        EndpointConfig(f"udpout:127.0.0.1:{c.getsockname()[1]}", outputs=(("attitude_hz", 5.0),))],
        tmp_path / "state")
    try:
        gcs, ap, slow = service.endpoints
        assert _rates(gcs) == DEFAULT_HZ
        assert _rates(ap) == AUTOPILOT_HZ
        assert _rates(slow) == {**DEFAULT_HZ, ATT: 5.0}
        # a peer on the autopilot endpoint asks for ATTITUDE at 10 Hz: only that endpoint changes
        peer = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        cmd = peer.command_long_encode(1, 200, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, ATT, 100_000, 0, 0, 0, 0, 0)
        ap._parse(bytes(cmd.pack(peer)))
        assert _rates(ap) == {**AUTOPILOT_HZ, ATT: 10.0}
        assert _rates(gcs) == DEFAULT_HZ and _rates(slow)[ATT] == 5.0
        # "0 = default" restores that endpoint's own default (off for the autopilot profile)
        cmd = peer.command_long_encode(1, 200, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, ATT, 0, 0, 0, 0, 0, 0)
        ap._parse(bytes(cmd.pack(peer)))
        assert _rates(ap)[ATT] == 0.0
        # the SR_ parameter is the daemon-wide rate: every endpoint following it, not an override
        ok, _ = service.params.set("SR_ATTITUDE", 20.0)
        assert ok
        assert _rates(gcs)[ATT] == 20.0 and _rates(ap)[ATT] == 0.0 and _rates(slow)[ATT] == 5.0
        ok, _ = service.params.set("SR_VISION_POS", 20.0)
        assert ok and _rates(ap)[VPE] == 20.0 and _rates(gcs)[VPE] == 20.0
    finally:
        stop_service(service, loop)
        for s in (a, b, c):
            s.close()


def _collect(socks: dict[str, socket.socket], seconds: float) -> dict[str, dict[str, int]]:
    parsers = {}
    for name in socks:
        p = mavlink.MAVLink(None)
        p.robust_parsing = True
        parsers[name] = p
    counts: dict[str, dict[str, int]] = {n: {} for n in socks}
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        idle = True
        for name, s in socks.items():
            try:
                data = s.recv(4096)
            except BlockingIOError:
                continue
            idle = False
            for m in parsers[name].parse_buffer(data) or ():
                if m.get_srcComponent() == 200:
                    counts[name][m.get_type()] = counts[name].get(m.get_type(), 0) + 1
        if idle:
            time.sleep(0.002)
    return counts


def test_ahrsd_run_sends_each_endpoint_its_profile(tmp_path):
    gcs, ap = udp_sink(), udp_sink()
    cfg = tmp_path / "ahrsd.toml"
    cfg.write_text(f"""
[[endpoint]]
url = "udpout:127.0.0.1:{gcs.getsockname()[1]}"
outputs = {{ highres_imu_hz = 0.0 }}
[[endpoint]]
url = "udpout:127.0.0.1:{ap.getsockname()[1]}"
profile = "autopilot"
""")
    save_mag_calibration(tmp_path / "state", sim_chip_mag_model())      # no heading is sent on an uncalibrated one
    proc = subprocess.Popen([str(AHRSD), "run", "--config", str(cfg), "--sim", "static", *LOW_RATE, "--state-dir",
                             str(tmp_path / "state"), "--status-line", "off"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline:       # wait until the heading flows on the autopilot link
            if _collect({"ap": ap}, 0.5)["ap"].get("VISION_POSITION_ESTIMATE"):
                break
            assert proc.poll() is None, "ahrsd exited"
        _collect({"gcs": gcs, "ap": ap}, 0.3)     # drain what queued up on both before the window
        counts = _collect({"gcs": gcs, "ap": ap}, 3.0)
    finally:
        stop_process(proc)
        gcs.close()
        ap.close()
    streams = {"ATTITUDE", "ATTITUDE_QUATERNION", "VISION_POSITION_ESTIMATE", "HIGHRES_IMU", "SCALED_IMU",
               "SYS_STATUS", "HEARTBEAT"}
    got_ap = {t for t in counts["ap"] if t in streams}
    got_gcs = {t for t in counts["gcs"] if t in streams}
    assert got_ap == {"VISION_POSITION_ESTIMATE", "SYS_STATUS", "HEARTBEAT"}, counts["ap"]
    assert got_gcs == {"ATTITUDE", "ATTITUDE_QUATERNION", "VISION_POSITION_ESTIMATE", "SYS_STATUS",
                       "HEARTBEAT"}, counts["gcs"]
    # same rate of the heading on both links (the daemon-wide 30 Hz): counts over the same window agree
    assert abs(counts["ap"]["VISION_POSITION_ESTIMATE"] - counts["gcs"]["VISION_POSITION_ESTIMATE"]) <= 6
