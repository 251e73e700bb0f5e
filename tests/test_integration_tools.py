"""ahrsd with the tools around it: systemd (unit verification, sd_notify READY/WATCHDOG/STOPPING against a fake
NOTIFY_SOCKET), MAVLink 2 signing, and its serial and TCP endpoints. MAVProxy as an independent ground station:
tests/test_magcal_integration.py (it detects our vehicle and drives a mag-cal session over our link)."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from service_rig import stop_process
from support.ahrsd_process import LOW_RATE, OUR_COMP, Daemon

from ahrsd.daemon.mavlink_io import mavlink, mavutil

pytestmark = pytest.mark.slow     # a long file: started first under pytest-xdist (tests/conftest.py)

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze not available")
def test_systemd_unit_verifies(tmp_path):
    """`systemd-analyze verify` also checks that ExecStart exists: point it at this checkout's ahrsd."""
    unit = (REPO / "systemd" / "ahrsd.service").read_text()
    exe = Path(sys.executable).with_name("ahrsd")
    if not exe.exists():
        pytest.skip("the ahrsd console script is not installed in this environment")
    (tmp_path / "ahrsd.service").write_text(unit.replace("/usr/local/bin/ahrsd", str(exe)))
    r = subprocess.run(["systemd-analyze", "verify", str(tmp_path / "ahrsd.service")], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr
    for key in ("Type=notify", "WatchdogSec=", "Restart=on-failure", "DynamicUser=yes", "StateDirectory=ahrsd",
                "ConfigurationDirectory=ahrsd", "ProtectSystem=strict", "DevicePolicy=closed",
                "SupplementaryGroups=spi dialout"):
        assert key in unit


def test_notify_watchdog_and_signing(tmp_path):
    """Under a fake systemd: READY=1 after the first good estimate, WATCHDOG=1 while samples flow,
    STOPPING=1 on SIGTERM. With a signing key: unsigned state-changing commands and parameter writes are
    refused and counted, signed ones accepted, the key never appears in the log, the timestamp persists."""
    notify_path = tmp_path / "notify.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(notify_path))
    sock.settimeout(0.2)
    key = bytes(range(1, 33))
    (tmp_path / "key").write_text(key.hex())
    cfg = tmp_path / "ahrsd.toml"
    cfg.write_text(f'[signing]\nkey_file = "{tmp_path / "key"}"\n')
    env = {"NOTIFY_SOCKET": str(notify_path), "WATCHDOG_USEC": "1000000"}
    d = Daemon(tmp_path, "--config", str(cfg), *LOW_RATE, env=env, mag_calibrated=True)
    d.gcs.setup_signing(key, sign_outgoing=False, allow_unsigned_callback=lambda mav, mid: False)
    got: list[str] = []

    def drain(seconds: float) -> list[str]:
        """The fields received within `seconds` (also kept in `got`)."""
        window: list[str] = []
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            try:
                window.extend(sock.recv(4096).decode().split("\n"))
            except socket.timeout:
                pass
        got.extend(window)
        return window

    def backlog() -> None:
        """Read what was sent before now (the start's READY=1 and watchdogs), so a window counts only its own."""
        sock.setblocking(False)
        try:
            while True:
                got.extend(sock.recv(4096).decode().split("\n"))
        except BlockingIOError:
            pass
        finally:
            sock.settimeout(0.2)

    try:
        d.wait_active()
        backlog()
        assert "READY=1" in got
        # WATCHDOG_USEC = 1 s: one every 0.5 s, 8 in a 4 s window. >= 5 leaves 1.5 s of scheduling delay (load
        # 10 on 2 cores); one every 2 s (a wrong interval) gives at most 3
        assert drain(4.0).count("WATCHDOG=1") >= 5
        hb = d.recv("HEARTBEAT", 6.0)
        assert hb.get_signed()                      # our output is signed
        # unsigned, state-changing: refused
        d.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_ATTITUDE, 100_000)
        assert d.ack(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL).result == mavlink.MAV_RESULT_DENIED
        d.gcs.mav.param_set_send(d.sysid, OUR_COMP, b"SR_ATTITUDE", 5.0, mavlink.MAV_PARAM_TYPE_REAL32)
        assert d.recv("PARAM_VALUE", 2.0, lambda m: m.param_id == "SR_ATTITUDE").param_value == 50.0
        # unsigned, read-only: answered
        d.command(mavlink.MAV_CMD_GET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_ATTITUDE)
        assert d.ack(mavlink.MAV_CMD_GET_MESSAGE_INTERVAL).result == mavlink.MAV_RESULT_ACCEPTED
        # signed: accepted
        d.gcs.mav.signing.sign_outgoing = True
        d.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_ATTITUDE, 100_000, confirmation=0)
        assert d.ack(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL).result == mavlink.MAV_RESULT_ACCEPTED
        st = d.recv("SYS_STATUS", 6.0)
        assert st.errors_count1 >= 2                # unsigned refusals are counted
        d.proc.send_signal(signal.SIGTERM)
        assert d.proc.wait(10) == 0
        drain(0.5)
        assert "STOPPING=1" in got
        log = d.output()
        assert key.hex() not in log and "MAVLink signing on" in log
        assert int((d.state_dir / "signing_timestamp").read_text()) > 0
    finally:
        d.stop()
        sock.close()


def _free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _serial_pair() -> tuple[int, int, str]:
    """A raw pseudo-terminal pair: (master fd, slave fd, the slave's path) — the daemon opens the slave as it
    would an autopilot's TELEM port."""
    import pty
    import termios
    import tty

    master, slave = pty.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    termios.tcsetattr(slave, termios.TCSANOW, termios.tcgetattr(slave))
    return master, slave, os.ttyname(slave)


def _serial_check(master: int) -> tuple[set[str], object]:
    """Our message types seen on the pty's other side, and the ACK of a command sent back after our first
    HEARTBEAT (None if none came within 60 s)."""
    import select

    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    sender = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    seen: set[str] = set()
    ack = None
    end = time.monotonic() + 60
    sent = False
    while time.monotonic() < end and (not {"HEARTBEAT", "ATTITUDE"} <= seen or ack is None):
        r, _, _ = select.select([master], [], [], 0.3)
        if not r:
            continue
        for m in parser.parse_buffer(os.read(master, 4096)) or ():
            if m.get_srcComponent() != OUR_COMP:
                continue
            seen.add(m.get_type())
            if m.get_type() == "COMMAND_ACK":
                ack = m
            if m.get_type() == "HEARTBEAT" and not sent:
                os.write(master, sender.command_long_encode(
                    1, OUR_COMP, mavlink.MAV_CMD_GET_MESSAGE_INTERVAL, 0, 30, 0, 0, 0, 0, 0, 0).pack(sender))
                sent = True
    return seen, ack


def test_serial_and_tcp_endpoints_server_and_client_reconnect(tmp_path):
    """One daemon with three endpoints. A serial endpoint ("/dev/pts/N,115200", as for an autopilot's TELEM
    port): our HEARTBEAT and ATTITUDE come out of the other side of a pty pair, and a command sent back is
    acknowledged. tcpin: a second client after the first one left is served; tcp: the daemon keeps retrying
    until the peer listens, without blocking the loop (the tcpin client keeps receiving meanwhile)."""
    p_in, p_out = _free_tcp_port(), _free_tcp_port()
    master, slave, slave_path = _serial_pair()
    log = open(tmp_path / "ahrsd.log", "w")
    proc = subprocess.Popen([sys.executable, "-m", "ahrsd.cli", "run", "--mavlink", f"tcpin:127.0.0.1:{p_in}",
                             "--mavlink", f"tcp:127.0.0.1:{p_out}", "--mavlink", f"{slave_path},115200",
                             *LOW_RATE, "--state-dir", str(tmp_path / "s"), "--status-line", "off"],
                            stdout=log, stderr=subprocess.STDOUT, cwd=REPO)

    def attitudes(conn, timeout, wanted=20):
        """Count ATTITUDE from us, returning as soon as `wanted` arrived."""
        n = 0
        end = time.monotonic() + timeout
        while time.monotonic() < end and n < wanted:
            m = conn.recv_match(type="ATTITUDE", blocking=True, timeout=0.3)
            if m is not None and m.get_srcComponent() == OUR_COMP:
                n += 1
        return n

    def connect(url):
        end = time.monotonic() + 60
        while True:
            try:
                return mavutil.mavlink_connection(url, dialect="ardupilotmega", retries=0)
            except OSError:
                if time.monotonic() > end:
                    raise
                time.sleep(0.5)

    try:
        seen, ack = _serial_check(master)
        assert {"HEARTBEAT", "ATTITUDE"} <= seen, (tmp_path / "ahrsd.log").read_text()
        assert ack is not None and ack.result == mavlink.MAV_RESULT_ACCEPTED
        first = connect(f"tcp:127.0.0.1:{p_in}")
        assert attitudes(first, 30.0) == 20, (tmp_path / "ahrsd.log").read_text()
        first.close()
        time.sleep(0.5)
        second = connect(f"tcp:127.0.0.1:{p_in}")
        second.mav.command_long_send(1, OUR_COMP, mavlink.MAV_CMD_GET_MESSAGE_INTERVAL, 0, 30, 0, 0, 0, 0, 0, 0)
        ack = second.recv_match(type="COMMAND_ACK", blocking=True, timeout=8)
        assert ack is not None and ack.result == mavlink.MAV_RESULT_ACCEPTED
        assert attitudes(second, 10.0) == 20
        second.close()
        server = mavutil.mavlink_connection(f"tcpin:127.0.0.1:{p_out}", dialect="ardupilotmega")
        assert attitudes(server, 15.0) == 20       # the daemon's tcp: endpoint found us
        server.close()
        assert proc.poll() is None
    finally:
        stop_process(proc)
        log.close()
        os.close(master)
        os.close(slave)
