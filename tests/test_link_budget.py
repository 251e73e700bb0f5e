"""The serial link budget: the warning for a 57600-baud endpoint with the default outputs, and priority dropping
on a line (a pipe, stepped in simulated time) whose reader is slower than the outputs.

Truth for the byte counts: the full payload lengths of common.xml (HEARTBEAT 9, SYS_STATUS 43, ATTITUDE 28,
ATTITUDE_QUATERNION 48, VISION_POSITION_ESTIMATE 117, HIGHRES_IMU 63 bytes), + 12 bytes of MAVLink 2 header
and CRC, + 13 when signed, at the documented default rates; a 57600-baud 8N1 line carries 5760 B/s.
"""

from __future__ import annotations

import array
import asyncio
import fcntl
import logging
import os
import termios
import tty
from dataclasses import dataclass

import pytest

from ahrsd.daemon.config import EndpointConfig
from ahrsd.daemon.mavlink_io import Endpoint, mavlink
from service_rig import start_service_on, stop_service

PAYLOAD = {0: 9, 1: 43, 30: 28, 31: 48, 102: 117, 105: 63}
DEFAULT_HZ = {0: 1.0, 1: 1.0, 30: 50.0, 31: 10.0, 102: 30.0, 105: 10.0}
LINE_57600_B_S = 5760.0


def expected_load(rates: dict[int, float], signed: bool) -> float:
    return sum(hz * (12 + PAYLOAD[mid] + (13 if signed else 0)) for mid, hz in rates.items())


@pytest.fixture
def pty_pair():
    master, slave = os.openpty()
    tty.setraw(master)
    name = os.ttyname(slave)
    yield master, name
    os.close(master)
    os.close(slave)


def _warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING and "B/s" in r.getMessage()]


def test_57600_baud_with_default_outputs_warns_once_with_the_figures(tmp_path, pty_pair, caplog):
    _, dev = pty_pair
    caplog.set_level(logging.WARNING, logger="ahrsd")
    service, loop = start_service_on((EndpointConfig(f"{dev},57600"),), tmp_path / "state")
    try:
        texts = _warnings(caplog)
        assert len(texts) == 1, texts
        need = expected_load(DEFAULT_HZ, signed=False)           # 7296 B/s
        assert f"{need:.0f} B/s" in texts[0]
        assert f"{100 * need / LINE_57600_B_S:.0f} %" in texts[0] and "5760 B/s" in texts[0]
        # what to lower: the largest stream the autopilot does not use comes first
        assert texts[0].index("ATTITUDE (50 Hz") < texts[0].index("HIGHRES_IMU")
        assert "VISION_POSITION_ESTIMATE (" not in texts[0]
        # a rate change that keeps it above 80 %: no second warning (once per excursion)
        ok, _ = service.params.set("SR_ATTITUDE", 40.0)
        assert ok and len(_warnings(caplog)) == 1
        # below the threshold, then above again: warned again, with the new figures
        ok, _ = service.params.set("SR_ATTITUDE", 0.0)
        ok2, _ = service.params.set("SR_HIGHRES_IMU", 0.0)
        assert ok and ok2 and len(_warnings(caplog)) == 1
        ok, _ = service.params.set("SR_ATTITUDE", 50.0)
        texts = _warnings(caplog)
        assert len(texts) == 2
        assert f"{expected_load({**DEFAULT_HZ, 105: 0.0}, False):.0f} B/s" in texts[1]
    finally:
        stop_service(service, loop)


def test_autopilot_profile_fits_57600_even_signed(tmp_path, pty_pair, caplog):
    _, dev = pty_pair
    key = tmp_path / "key"
    key.write_bytes(bytes(range(32)))
    caplog.set_level(logging.WARNING, logger="ahrsd")
    from ahrsd.daemon.config import SigningConfig
    service, loop = start_service_on((EndpointConfig(f"{dev},57600", profile="autopilot"),), tmp_path / "state",
                                     signing=SigningConfig(key_file=str(key), refuse_unsigned_commands=False))
    try:
        assert _warnings(caplog) == []
        budget = service.endpoints[0].budget
        rates = {0: 1.0, 1: 1.0, 102: 30.0}
        assert budget.fraction == pytest.approx(expected_load(rates, signed=True) / LINE_57600_B_S)
        # a GCS behind the autopilot asks this link for ATTITUDE at 50 Hz: checked again, warned
        peer = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        cmd = peer.command_long_encode(1, 200, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 30, 20_000, 0, 0, 0, 0, 0)
        service.endpoints[0]._parse(bytes(cmd.pack(peer)))
        texts = _warnings(caplog)
        assert len(texts) == 1
        assert f"{expected_load({**rates, 30: 50.0}, signed=True):.0f} B/s (signed)" in texts[0]
    finally:
        stop_service(service, loop)


def _attitude():
    return mavlink.MAVLink_attitude_message(1, 0.1, 0.2, 0.3, 0.01, 0.02, 0.03)


def _vpe(i):
    return mavlink.MAVLink_vision_position_estimate_message(i, 0.0, 0.0, 0.0, 0.1, 0.2, 0.3,
                                                            [1e4, 0, 0, 0, 0, 0, 1e4, 0, 0, 0, 0, 1e4, 0, 0, 0,
                                                             1e-4, 0, 0, 1e-4, 0, 1e-4], 0)


def _highres():
    return mavlink.MAVLink_highres_imu_message(1, 0.1, 0.2, 9.8, 0.01, 0.02, 0.03, 0.2, 0.0, 0.4,
                                               0, 0, 0, 25.0, 0x11FF, 0)


def _heartbeat():
    return mavlink.MAVLink_heartbeat_message(40, 8, 0, 0, 4, 3)


LINE_BUFFER_B = 4096
"""The pipe standing for the line holds one page: a UART's kernel transmit buffer (UART_XMIT_SIZE)."""


class _PipeConnection:
    """What the endpoint needs of a pymavlink serial connection (its descriptor, its packer, close) on the
    write end of a pipe."""

    def __init__(self, fd: int, source_system: int, source_component: int):
        self.fd = fd
        self.mav = mavlink.MAVLink(None, srcSystem=source_system, srcComponent=source_component)

    def close(self) -> None:
        pass                                          # the test owns the pipe


@dataclass
class _PipeLineEndpoint(Endpoint):
    """A serial endpoint (its out queue, priorities and sends are the daemon's) whose line is a pipe the test
    reads at the simulated line's rate. A pipe hands written bytes to its reader, and tells its writer it has
    room, within the write and read calls themselves; a pty does both in deferred kernel work, late on a loaded
    machine, where a few ms are seconds of this test's line, so the result depended on the machine's load."""

    line_fd: int = -1

    def _make_connection(self):
        return _PipeConnection(self.line_fd, self.source_system, self.source_component)


@pytest.fixture
def pipe_line():
    read_fd, write_fd = os.pipe()
    fcntl.fcntl(write_fd, fcntl.F_SETPIPE_SZ, LINE_BUFFER_B)
    os.set_blocking(read_fd, False)
    yield read_fd, write_fd
    os.close(read_fd)
    os.close(write_fd)


def _in_pipe(fd: int) -> int:
    buf = array.array("i", [0])
    fcntl.ioctl(fd, termios.FIONREAD, buf, True)
    return buf[0]


def _count(parser, data: bytes, received: dict[str, int]) -> int:
    """Count the whole frames in `data` by type into `received`; returns the number of bad ones."""
    bad = 0
    for m in parser.parse_buffer(data) or ():
        if m.get_type() == "BAD_DATA":
            bad += 1
        else:
            received[m.get_type()] = received.get(m.get_type(), 0) + 1
    return bad


def test_slow_reader_drops_lowest_priority_first_and_never_cuts_a_frame(pipe_line):
    """The reader takes 3000 B/s; we offer VPE 20 Hz + HEARTBEAT 1 Hz (2.6 kB/s, fits), ATTITUDE 50 Hz and
    HIGHRES_IMU 20 Hz (3.5 kB/s more) through a 57600-baud serial endpoint with the daemon's priorities, built
    alone. Simulated time in 10 ms steps, the event loop run once per step: no wall time anywhere, so the
    counts are the same at any load.

    The line is a pipe (`_PipeLineEndpoint`), which hides its buffer from TIOCOUTQ as a pty does (a UART reports
    it): the queue is given 2 s of line time (`serial_queue_s`) so that the hidden page is not mistaken for
    the line falling behind."""
    from ahrsd.daemon.link_budget import line_bytes_per_s, priority_of

    read_fd, write_fd = pipe_line
    ep = _PipeLineEndpoint("line,57600", 1, 200, lambda _ep, _msg: None, line_bytes_per_s=line_bytes_per_s(57600),
                           priority_of=priority_of, serial_queue_s=2.0, line_fd=write_fd)
    loop = asyncio.new_event_loop()
    ep.open(loop)
    assert ep.out_queue is not None and ep.out_queue.capacity_bytes == 2 * 5760
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    received: dict[str, int] = {}
    bad = 0
    offered: dict[str, int] = {}
    step_s, reader_b_s = 0.01, 3000.0
    tx0 = ep.counters.tx_messages                     # (0: nothing sent before)
    credit = 0.0                                      # bytes the reader may still take
    try:
        for k in range(6000):                         # 60 s of line time
            due = []
            if k % 5 == 0:
                due.append(_vpe(k))                   # 20 Hz
            if k % 100 == 0:
                due.append(_heartbeat())
            if k % 2 == 0:
                due.append(_attitude())               # 50 Hz
            if k % 5 == 2:
                due.append(_highres())                # 20 Hz
            for m in due:
                offered[m.get_type()] = offered.get(m.get_type(), 0) + 1
                ep.send(m)
            # the line takes reader_b_s of simulated time; what it could not take (nothing waiting) is kept
            credit += reader_b_s * step_s
            data = os.read(read_fd, min(int(credit), _in_pipe(read_fd))) if _in_pipe(read_fd) and credit >= 1 else b""
            credit -= len(data)
            bad += _count(parser, data, received)
            loop.run_until_complete(asyncio.sleep(0))  # the writer callback moves the queue into the room made
        sent, dropped = ep.counters.tx_messages - tx0, ep.counters.tx_dropped
        by_prio = dict(ep.counters.tx_dropped_by_priority)
        for _ in range(100):                          # the reader takes what is still buffered
            if not (_in_pipe(read_fd) or ep.out_queue.waiting_bytes()):
                break
            bad += _count(parser, os.read(read_fd, 65536) if _in_pipe(read_fd) else b"", received)
            loop.run_until_complete(asyncio.sleep(0))
        assert ep.out_queue.waiting_bytes() == 0
    finally:
        ep.close()
        loop.close()
    assert bad == 0                                        # no frame cut by a partial write
    assert dropped > 0                                     # the link was over-subscribed
    assert by_prio.get(0, 0) == 0                          # the heading and the heartbeat always got through
    # HIGHRES_IMU (priority 3) refused more often than ATTITUDE (2)
    assert by_prio.get(3, 0) / offered["HIGHRES_IMU"] > by_prio.get(2, 0) / offered["ATTITUDE"] > 0
    # what was dropped never reached the wire; what was accepted did (minus what is still queued)
    assert sent + dropped == sum(offered.values())
    assert received["VISION_POSITION_ESTIMATE"] == offered["VISION_POSITION_ESTIMATE"]
    assert received["HEARTBEAT"] == offered["HEARTBEAT"]
    assert sum(received.values()) == sent
    frac = {t: received.get(t, 0) / offered[t] for t in offered}
    assert frac["VISION_POSITION_ESTIMATE"] > frac["ATTITUDE"] > frac["HIGHRES_IMU"]
