"""Our TIMESYNC answers against a PX4-style peer: after PX4's convergence window the time PX4 gives our
VISION_POSITION_ESTIMATE (`sync_stamp(usec)`) is the true sample instant within ±2 ms.

The peer implements PX4's offset estimator as in src/lib/timesync/Timesync.cpp (and
src/modules/mavlink/mavlink_timesync.cpp): offset = (ts1 + now − 2·tc1)/2 in µs from a request it sent
(ts1, its clock in ns) and our answer (tc1, ours in ns); samples with an RTT ≥ 10 ms are ignored; the
double-exponential filter's gains go from 0.05 to 0.003 over CONVERGENCE_WINDOW = 500 exchanges, until then
sync_stamp returns the arrival time. Its clock runs 987.654321 s ahead of ours and 100 ppm fast (a crystal's
error). Truth: the peer's clock at the instant `usec` names on ours (`usec` is the daemon's stamp of the
sample; bench/latency.py part B measures it 0.05 ms from the simulated chip's real ready time).
The peer asks at 100 Hz (PX4 asks at 10 Hz) so the 500 exchanges take 5 s, not 50: the daemon answers each
sender (system and component id) up to 20 times a second (daemon/timesync_answers.py), so the requests take turns
among SENDERS component ids of the peer's system, each asking at 20 Hz, within its limit. Like PX4's receive
thread, it takes a datagram's arrival time when it arrives (the kernel's SO_TIMESTAMPNS), not when this test
process gets round to reading it.
"""

from __future__ import annotations

import math
import select
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from ahrsd.daemon.mavlink_io import SO_TIMESTAMPNS, TIMESPEC, Endpoint, mavlink
from service_rig import stop_process
from bench.sim_calibration import save_mag_calibration, sim_chip_mag_model
from support.ahrsd_process import LOW_RATE

pytestmark = pytest.mark.slow     # a long file: started first under pytest-xdist (tests/conftest.py)

AHRSD = Path(sys.executable).with_name("ahrsd")
OFFSET_US = 987_654_321.0
SKEW = 1e-4
CONVERGENCE_WINDOW = 500
MAX_RTT_US = 10_000
MAX_DEVIATION_US = 100_000
ALPHA0 = BETA0 = 0.05
ALPHA1 = BETA1 = 0.003
REQUEST_HZ = 100.0
SENDERS = 5            # component ids the requests take turns among: 100 Hz / 5 = each sender's 20 answers a second


class Px4Timesync:
    def __init__(self):
        self.sequence = 0
        self.offset_us = 0.0
        self.skew = 0.0
        self.high_deviation = 0

    @property
    def converged(self) -> bool:
        return self.sequence >= CONVERGENCE_WINDOW

    def update(self, now_us: int, tc1_ns: int, ts1_ns: int) -> None:
        offset = ((ts1_ns // 1000) + now_us - (tc1_ns // 1000) * 2) / 2
        if now_us - ts1_ns // 1000 >= MAX_RTT_US:
            return
        if self.converged and abs(self.offset_us - offset) > MAX_DEVIATION_US:
            self.high_deviation += 1
            if self.high_deviation > 5:
                self.__init__()
            return
        if not self.converged:
            p = 1.0 - math.exp(0.5 * (1.0 - 1.0 / (1.0 - self.sequence / CONVERGENCE_WINDOW)))
            alpha, beta = p * ALPHA1 + (1 - p) * ALPHA0, p * BETA1 + (1 - p) * BETA0
        else:
            alpha, beta = ALPHA1, BETA1
        prev = self.offset_us
        if self.sequence == 0:
            self.offset_us = offset
        else:
            self.offset_us = alpha * offset + (1 - alpha) * (self.offset_us + self.skew)
            self.skew = beta * (self.offset_us - prev) + (1 - beta) * self.skew
        self.sequence += 1
        self.high_deviation = 0


def test_px4_stamps_our_samples_within_2_ms(tmp_path):
    t_ref_us = time.monotonic_ns() / 1000

    def peer_us_of_ours(our_us: float) -> float:
        return t_ref_us + OFFSET_US + (our_us - t_ref_us) * (1 + SKEW)

    def peer_now_us() -> float:
        return peer_us_of_ours(time.monotonic_ns() / 1000)

    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.setblocking(False)
    sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
    save_mag_calibration(tmp_path / "st", sim_chip_mag_model())      # no heading is sent on an uncalibrated one
    # the chip at a quarter of its rate (LOW_RATE): each VPE's usec is still a sample's stamp, which is what the
    # peer's time is checked against, and the daemon and its reader take a quarter of the samples
    proc = subprocess.Popen([str(AHRSD), "run", "--sim", "static", *LOW_RATE, "--mavlink",
                             f"udpout:127.0.0.1:{sock.getsockname()[1]}", "--state-dir", str(tmp_path / "st"),
                             "--status-line", "off"], stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
    px4 = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    sync = Px4Timesync()
    errors_ms, before_ms = [], []
    addr = None
    next_request = time.monotonic()
    requests = 0
    deadline = time.monotonic() + 300      # a give-up time only: the run ends at 300 VPEs, however slowly a loaded
                                           # machine sends them (the count, not the time, is the evidence)
    try:
        while time.monotonic() < deadline and len(errors_ms) < 300:
            now = peer_now_us()
            try:
                data, anc, _, addr = sock.recvmsg(4096, socket.CMSG_SPACE(TIMESPEC.size))
                sec, nsec = TIMESPEC.unpack_from(anc[0][2])
                arrival_ns = sec * 10**9 + nsec - (time.time_ns() - time.monotonic_ns())
                now = peer_us_of_ours(arrival_ns / 1000)
            except BlockingIOError:
                data = b""
                # sleep until a datagram arrives or the next request is due, instead of polling: arrival times are
                # the kernel's stamps, so how soon this loop wakes does not change them
                wait_s = 0.01 if addr is None else next_request - time.monotonic()
                select.select([sock], [], [], min(max(wait_s, 0.0), 0.01))
            for m in parser.parse_buffer(data) or ():
                if m.get_type() == "TIMESYNC" and m.tc1 > 0:
                    sync.update(int(now), m.tc1, m.ts1)
                elif m.get_type() == "VISION_POSITION_ESTIMATE":
                    stamped = m.usec + sync.offset_us if sync.converged else now     # sync_stamp()
                    (errors_ms if sync.converged else before_ms).append(
                        (stamped - peer_us_of_ours(m.usec)) / 1000)
            if addr is not None and time.monotonic() >= next_request:
                next_request += 1.0 / REQUEST_HZ
                px4.srcComponent = 1 + requests % SENDERS
                requests += 1
                sock.sendto(bytes(px4.timesync_encode(0, int(peer_now_us() * 1000)).pack(px4)), addr)
            assert proc.poll() is None, "ahrsd exited"
    finally:
        stop_process(proc)
        sock.close()
    err = np.array(errors_ms)
    assert len(err) >= 300, f"only {len(err)} VPEs after convergence (sequence {sync.sequence})"
    assert np.all(np.abs(err) < 2.0), (err.min(), err.max())
    before = f"; before convergence (arrival time) median {np.median(before_ms):+.3f} ms" if before_ms else ""
    print(f"\nPX4-style stamp − true sample instant: {np.median(err):+.3f} ms median, "
          f"[{err.min():+.3f}, {err.max():+.3f}] ms over {len(err)} VPEs{before}")


def test_timesync_answer_is_stamped_at_the_middle_of_arrival_and_answer(tmp_path):
    """A request that waited 50 ms for the event loop: tc1 is the midpoint of its kernel arrival time and the
    answer, not the answer time (which would shift the requester's offset by half the wait)."""
    import asyncio
    from service_rig import free_udp_port

    port = free_udp_port()
    got = []
    loop = asyncio.new_event_loop()
    ep = Endpoint(f"udpin:127.0.0.1:{port}", 1, 200, lambda e, m: got.append((m, e.rx_monotonic_ns, e.timesync_stamp_ns(),
                                                                        time.monotonic_ns())))
    ep.open(loop)
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        t_send = time.monotonic_ns()
        peer.sendto(bytes(mav.timesync_encode(0, 12345).pack(mav)), ("127.0.0.1", port))
        time.sleep(0.05)                       # the loop is busy elsewhere
        t_read = time.monotonic_ns()
        loop.run_until_complete(asyncio.sleep(0.01))
        assert got and got[0][0].get_type() == "TIMESYNC"
        _, arrival, tc1, answered = got[0]
        assert t_send <= arrival < t_read                        # the kernel's arrival time, before the read
        waited = answered - arrival                              # ≥ 50 ms
        assert abs(tc1 - (arrival + answered) / 2) < waited / 4  # the middle, not either end
    finally:
        ep.close()
        peer.close()
        loop.close()
