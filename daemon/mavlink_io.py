"""MAVLink connections registered with the asyncio event loop (pymavlink mavutil connections,
read through loop.add_reader on their fd).

One `Endpoint` per configured URL wraps a pymavlink `mavfile`. Reception is event driven:
`loop.add_reader(fd, ...)` drains every byte available and parses it (no polling, no reader threads).
Malformed input (bad CRC, bad prefix, bad signature, truncated frames) is counted, never raised.

pymavlink picks its wire protocol and dialect when `mavutil` is first imported, so this module sets
MAVLINK20=1 and MAVLINK_DIALECT=ardupilotmega before importing it, and re-selects the dialect if someone
imported mavutil earlier with other settings.
"""

from __future__ import annotations

import asyncio
import errno
import logging
import os
import socket
import struct
import sys
import time
from dataclasses import dataclass, field
from typing import Callable

os.environ["MAVLINK20"] = "1"
os.environ["MAVLINK_DIALECT"] = "ardupilotmega"

from pymavlink import mavutil  # noqa: E402  (must follow the environment set-up)

if mavutil.mavlink.WIRE_PROTOCOL_VERSION != "2.0" or mavutil.current_dialect != "ardupilotmega":
    mavutil.set_dialect("ardupilotmega")

mavlink = mavutil.mavlink   # the ardupilotmega MAVLink 2 module: message classes and enums

from ahrsd.core import udp_drops  # noqa: E402
from ahrsd.daemon.mavlink_frame import FramePacker  # noqa: E402
from ahrsd.daemon.serial_queue import QUEUE_SECONDS, SerialOutQueue  # noqa: E402

log = logging.getLogger(__name__)

READ_CHUNK = 4096          # bytes per read on stream links
UDP_MAX_DATAGRAM = 65535
# Linux SO_TIMESTAMPNS (asm-generic/socket.h; Python's socket module does not export it): the kernel's
# CLOCK_REALTIME arrival time of each datagram, as a struct timespec in the ancillary data
SO_TIMESTAMPNS = 35 if sys.platform == "linux" else None
TIMESPEC = struct.Struct("@qq")
UDP_KINDS = ("udpin", "udpout", "udpbcast", "udp")
MAX_READS_PER_WAKE = 64    # bound the work done per readiness callback (datagrams or chunks)
TCP_RETRY_S = 2.0


def max_frame_bytes(message_id: int, signed: bool = False) -> int:
    """The largest MAVLink 2 frame of this message id, in bytes: 10 header + the full payload + 2 CRC, + 13 when
    signed (link id, 48-bit timestamp, 48-bit signature; MAVLink 2 trims trailing zero bytes of the payload, so a
    frame is never larger)."""
    return 12 + mavlink.mavlink_map[message_id].unpacker.size + (13 if signed else 0)


_FRAMES = FramePacker()         # the unsigned frames every endpoint sends (one payload packer per message class)
_SIZER = mavlink.MAVLink(None)   # packs a message only to learn its length: no file, no signing, its seq never moves


def frame_bytes(msg, signed: bool = False) -> int:
    """The MAVLink 2 frame `msg` packs to, in bytes: what a link's write hands its serial queue (the payload's
    trailing zero bytes trimmed), + 13 when signed. Packing again at `send` sets the same fields of `msg` anew."""
    return len(msg.pack(_SIZER)) + (13 if signed else 0)


@dataclass
class LinkCounters:
    rx_messages: int = 0
    rx_malformed: int = 0      # BAD_DATA: bad prefix, CRC, length, unknown message
    rx_bad_signature: int = 0  # signature or timestamp check failed (counted separately from malformed)
    rx_unknown: int = 0        # well-formed frames of message ids outside our dialect (not delivered)
    tx_messages: int = 0
    tx_errors: int = 0
    tx_dropped: int = 0        # refused by a serial link that could not keep up (daemon.serial_queue)
    tx_dropped_by_priority: dict = field(default_factory=dict)   # priority -> count
    reconnects: int = 0
    # a UDP link's datagrams the kernel dropped, its receive buffer full while the daemon did not read (a stall
    # on a loaded machine): only the kernel can count them (core.udp_drops), read when the link closes
    rx_dropped_by_kernel: int = 0


MessageHandler = Callable[["Endpoint", object], None]


class EndpointOpenError(OSError):
    """A UDP/TCP server address the daemon cannot open (not a local address, a port taken): a configuration
    error. Its text names the endpoint and the reason, without the "[Errno N]" that OSError puts first, in
    the form the other start failures take (`ahrsd run: error: …`, `ahrsd cannot start: …`)."""

    def __str__(self) -> str:
        return f"MAVLink endpoint {self.filename}: {self.strerror}"


def check_endpoint_opens(url: str) -> None:
    """Open and close the connection `Endpoint.open` will make for `url`, so that a server address the
    daemon cannot have is refused before the estimator's compile (EndpointOpenError). A TCP client and a
    serial port are not tried: the daemon retries those in the background (a peer or adapter may come later)."""
    probe = Endpoint(url, 1, 1, lambda _ep, _msg: None)
    if probe.kind in ("tcp", "serial"):
        return
    try:
        conn = probe._make_connection()
    except OSError as exc:
        raise EndpointOpenError(exc.errno, exc.strerror or str(exc), url) from exc
    conn.close()


@dataclass
class Endpoint:
    """A pymavlink connection whose input is delivered to `on_message(endpoint, msg)` from the event loop."""

    url: str
    source_system: int
    source_component: int
    on_message: MessageHandler
    counters: LinkCounters = field(default_factory=LinkCounters)
    conn: object | None = None
    _loop: asyncio.AbstractEventLoop | None = None
    _fd: int | None = None
    _signing: dict | None = None
    _connect_task: asyncio.Task | None = None
    # what this endpoint gets (set by the service, daemon.endpoint_outputs): its own OutputSchedule, the
    # profile and overrides it was built from
    schedule: object | None = None
    profile: str = "gcs"
    overrides_hz: dict = field(default_factory=dict)
    # serial links: the line's byte rate and the message priority function switch on the non-blocking
    # priority queue (daemon.serial_queue); None = pymavlink writes directly
    line_bytes_per_s: float | None = None
    priority_of: Callable[[int], int] | None = None
    serial_queue_s: float = QUEUE_SECONDS     # the line time the queue may hold (daemon.serial_queue)
    out_queue: SerialOutQueue | None = None
    budget: object | None = None       # daemon.link_budget.LinkBudget of a serial endpoint
    # CLOCK_MONOTONIC ns at which the input being parsed arrived: the kernel's time stamp of a UDP datagram
    # (SO_TIMESTAMPNS), else the start of the read; for TIMESYNC answers (`timesync_stamp_ns`)
    rx_monotonic_ns: int | None = None
    _rx_timestamps: bool = False
    # every frame in and out, as its raw bytes (daemon.vehicle_log: TlogLog.put, a queue append); None = off
    traffic_log: Callable[[bytes], object] | None = None

    @property
    def kind(self) -> str:
        return self.url.split(":", 1)[0] if ":" in self.url and not self.url.startswith("/") else "serial"

    @property
    def connected(self) -> bool:
        return self.conn is not None

    # -- lifecycle ------------------------------------------------------------------------------------------

    def open(self, loop: asyncio.AbstractEventLoop) -> None:
        """Open the connection now, or in the background: a TCP client (its constructor blocks) and a serial
        port that is not there yet (USB adapter unplugged) are retried every TCP_RETRY_S. A bad UDP/TCP
        server address raises: that is a configuration error."""
        self._loop = loop
        if self.kind == "tcp":
            self._connect_task = loop.create_task(self._connect_retrying())
            return
        try:
            conn = self._make_connection()
        except OSError as exc:
            if self.kind != "serial":   # a configuration error: say which endpoint (the OS error names none)
                raise EndpointOpenError(exc.errno, exc.strerror or str(exc), self.url) from exc
            log.warning("MAVLink %s: %s; retrying every %.0f s", self.url, exc, TCP_RETRY_S)
            self._connect_task = loop.create_task(self._connect_retrying())
            return
        self._attach(conn)

    def _make_connection(self):
        conn = mavutil.mavlink_connection(self.url, source_system=self.source_system,
                                          source_component=self.source_component, dialect="ardupilotmega",
                                          autoreconnect=False, retries=0)
        conn.mav.robust_parsing = True
        return conn

    async def _connect_retrying(self) -> None:
        failures = 0
        while True:
            try:
                conn = await self._loop.run_in_executor(None, self._make_connection)
            except OSError as exc:
                failures += 1
                log.log(logging.INFO if failures == 1 else logging.DEBUG,
                        "MAVLink %s: %s; retrying every %.0f s", self.url, exc, TCP_RETRY_S)
                await asyncio.sleep(TCP_RETRY_S)
                continue
            self._attach(conn)
            log.info("MAVLink %s connected", self.url)
            return

    def _attach(self, conn) -> None:
        self.conn = conn
        if self._signing is not None:
            self._apply_signing()
        self._rx_timestamps = False
        if self.kind in UDP_KINDS and SO_TIMESTAMPNS is not None:
            try:
                conn.port.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
                self._rx_timestamps = True
            except (OSError, AttributeError):
                pass
        if self.kind == "serial" and self.line_bytes_per_s and conn.fd is not None:
            self.out_queue = SerialOutQueue(conn.fd, self.line_bytes_per_s, self._loop, self.counters,
                                            queue_s=self.serial_queue_s)
            conn.mav.file = self.out_queue
        self._register_fd()

    def _register_fd(self) -> None:
        fd = self.conn.fd if self.conn is not None else None   # every pymavlink connection (mavfile) has one
        if fd == self._fd:
            return
        if self._fd is not None:
            self._loop.remove_reader(self._fd)
        self._fd = fd
        if fd is not None:
            self._loop.add_reader(fd, self._on_readable)

    def _drop_out_queue(self) -> None:
        if self.out_queue is not None:
            self.out_queue.close()
            self.out_queue = None

    def close(self) -> None:
        if self._connect_task is not None:
            self._connect_task.cancel()
        self._count_kernel_drops()
        self._drop_out_queue()
        if self._fd is not None and self._loop is not None:
            self._loop.remove_reader(self._fd)
            self._fd = None
        if self.conn is not None:
            try:
                self.conn.close()
            except OSError:
                pass
            self.conn = None

    def _count_kernel_drops(self) -> None:
        """What the kernel dropped on a UDP link's socket since it opened (core.udp_drops), while it is still open."""
        fd = self.conn.fd if self.conn is not None else None
        if fd is None or not self.kind.startswith("udp"):
            return
        try:
            self.counters.rx_dropped_by_kernel = udp_drops.socket_drops(fd)
        except (LookupError, OSError):      # no /proc (another OS): not counted, as before
            pass

    # -- identity and signing ---------------------------------------------------------------------------------

    def set_system_id(self, sysid: int) -> None:
        self.source_system = sysid
        if self.conn is not None:
            self.conn.mav.srcSystem = sysid
            self.conn.source_system = sysid

    def enable_signing(self, key: bytes, link_id: int, initial_timestamp: int,
                       allow_unsigned: Callable[[object, int], bool]) -> None:
        self._signing = dict(secret_key=key, sign_outgoing=True, allow_unsigned_callback=allow_unsigned,
                             initial_timestamp=initial_timestamp, link_id=link_id)
        if self.conn is not None:
            self._apply_signing()

    def _apply_signing(self) -> None:
        from ahrsd.daemon.signing import verify_signature_before_timestamp

        self.conn.setup_signing(**self._signing)
        verify_signature_before_timestamp(self.conn.mav)

    def signing_timestamp(self) -> int:
        if self.conn is None or self._signing is None:
            return 0
        return int(self.conn.mav.signing.timestamp)

    # -- I/O --------------------------------------------------------------------------------------------------

    def send_together(self, msgs) -> bool:
        """Send every one of `msgs` or none (the chunks of one STATUSTEXT: a receiver shows a text only whole): a
        serial link whose queue would refuse one of them sends none and counts them all as dropped. Each frame is
        taken at the size it packs to, as `send` hands it to the queue."""
        queue = self.out_queue
        if queue is not None:
            queue.priority = self.priority_of(msgs[0].get_msgId())
            signed = self._signing is not None
            if not queue.admits([frame_bytes(m, signed) for m in msgs]):
                queue.refuse(len(msgs))
                return False
        return all([self.send(m) for m in msgs])

    def send(self, msg) -> bool:
        """Pack and send one message on this link; errors are counted, never raised."""
        if self.conn is None:
            return False
        queue = self.out_queue
        if queue is not None:
            queue.priority = self.priority_of(msg.get_msgId())
        mav = self.conn.mav
        try:
            if not mav.signing.sign_outgoing and mav.send_callback is None:
                # what MAVLink.send does, the frame packed in one call (daemon.mavlink_frame: the same bytes)
                buf = _FRAMES.frame(msg, mav.seq, mav.srcSystem, mav.srcComponent)
                mav.file.write(buf)
                mav.seq = (mav.seq + 1) % 256
                mav.total_packets_sent += 1
                mav.total_bytes_sent += len(buf)
            else:
                mav.send(msg)
                buf = None
        except (OSError, ValueError, TypeError, OverflowError) as exc:
            self.counters.tx_errors += 1
            if self.conn is not None and self.conn.fd != self._fd:
                self._register_fd()
            if self.counters.tx_errors in (1, 100, 10000):
                log.warning("MAVLink %s: send of %s failed: %s", self.url, msg.get_type(), exc)
            return False
        if queue is not None and not queue.accepted_last:
            return False                      # the link is behind: refused by priority, counted
        self.counters.tx_messages += 1
        if self.traffic_log is not None:          # the bytes just packed (and signed) for this link
            self.traffic_log(msg.get_msgbuf() if buf is None else buf)
        if self.conn.fd != self._fd:          # pymavlink dropped a TCP client on a write error (tcpin)
            self._register_fd()
        return True

    def _read_chunk(self) -> bytes | None:
        """Bytes available now; b'' when drained; None when a stream peer closed."""
        conn = self.conn
        kind = self.kind
        if kind in ("tcp", "tcpin", "uds", "unix"):
            if kind == "tcpin" and conn.port is None:
                conn.recv(0)        # accept the pending client (pymavlink swaps fd to the accepted socket)
                self._register_fd()
                if conn.port is None:
                    return b""
            try:
                data = conn.port.recv(READ_CHUNK)
            except BlockingIOError:
                return b""
            except OSError:
                return None
            return data if data else None
        if kind == "serial":
            return conn.recv(READ_CHUNK) or b""
        if self._rx_timestamps:
            return self._recv_datagram_stamped()
        data = conn.recv()          # UDP: one datagram ("" when none)
        return data if data else b""

    def _recv_datagram_stamped(self) -> bytes:
        """One datagram with its kernel arrival time (what pymavlink's mavudp.recv does, plus the time)."""
        conn = self.conn
        try:
            data, ancillary, _flags, addr = conn.port.recvmsg(UDP_MAX_DATAGRAM, socket.CMSG_SPACE(TIMESPEC.size))
        except OSError as exc:
            if exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK, errno.ECONNREFUSED):
                return b""
            raise
        if conn.udp_server:                     # as mavudp.recv: remember the client to answer it
            conn.clients.add(addr)
            conn.clients_last_alive[addr] = time.time()    # host clock: pymavlink's own bookkeeping (mavudp)
        elif conn.broadcast:
            conn.last_address = addr
        for level, kind, payload in ancillary:
            if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(payload) >= TIMESPEC.size:
                sec, nsec = TIMESPEC.unpack_from(payload)
                # CLOCK_REALTIME -> CLOCK_MONOTONIC with the offset between the two clocks now
                realtime_minus_monotonic_ns = time.time_ns() - time.monotonic_ns()   # host clock: the kernel's
                self.rx_monotonic_ns = sec * 1_000_000_000 + nsec - realtime_minus_monotonic_ns
        return data

    def timesync_stamp_ns(self) -> int:
        """TIMESYNC `tc1` for a request being handled now, CLOCK_MONOTONIC ns (the clock of VPE `usec`).

        The requester computes offset = (ts1 + t_rx)/2 − tc1 (PX4 src/lib/timesync/Timesync.cpp), which is
        exact when tc1 is the middle of our part of the round trip. Our part runs from the request's arrival
        to the answer's departure, and includes the time the request waited for the event loop; stamping
        the midpoint of arrival and now takes that wait out (stamping `now` alone would shift the offset
        by half of it, ms under load)."""
        now = time.monotonic_ns()       # host clock: TIMESYNC answers in the host's CLOCK_MONOTONIC
        arrival = self.rx_monotonic_ns
        if arrival is None or not 0 <= now - arrival < 1_000_000_000:
            return now
        return (arrival + now) // 2

    def _on_readable(self) -> None:
        conn = self.conn
        if conn is None:
            return
        for _ in range(MAX_READS_PER_WAKE):
            self.rx_monotonic_ns = time.monotonic_ns()    # host clock: replaced by the kernel's time of a datagram
            try:
                data = self._read_chunk()
            except OSError as exc:
                log.warning("MAVLink %s: read failed: %s", self.url, exc)
                data = None
            if data is None:
                self._on_stream_closed()
                return
            if not data:
                break
            self._parse(data)
            if self.kind not in ("tcp", "tcpin", "uds", "unix", "serial"):
                self._end_of_datagram()
        self._register_fd()

    def _end_of_datagram(self) -> None:
        """MAVLink frames never span UDP datagrams: a partial frame left over is truncated input."""
        if self.conn.mav.buf_len() > 0:
            self.counters.rx_malformed += 1
            self._reset_parser()

    def _reset_parser(self) -> None:
        mav = self.conn.mav
        mav.buf = bytearray()
        mav.buf_index = 0
        mav.expected_length = mavlink.HEADER_LEN_V1 + 2   # the parser's initial state

    def _parse(self, data: bytes) -> None:
        mav = self.conn.mav
        try:
            msgs = mav.parse_buffer(data) or ()
        except Exception as exc:  # noqa: BLE001 - a hostile frame must never crash the daemon
            self.counters.rx_malformed += 1
            log.debug("MAVLink %s: unparsable input: %s", self.url, exc)
            self._reset_parser()
            return
        bad_prefix_seen = False
        for msg in msgs:
            if msg.get_type() == "BAD_DATA":
                reason = str(msg.reason)
                if "ignature" in reason:
                    self.counters.rx_bad_signature += 1
                elif "prefix" in reason:
                    if not bad_prefix_seen:          # a run of junk bytes counts once per read
                        self.counters.rx_malformed += 1
                        bad_prefix_seen = True
                else:
                    self.counters.rx_malformed += 1
                continue
            if msg.get_msgId() < 0:
                self.counters.rx_unknown += 1
                continue
            self.counters.rx_messages += 1
            if self.traffic_log is not None:
                self.traffic_log(msg.get_msgbuf())
            try:
                self.on_message(self, msg)
            except Exception:  # noqa: BLE001 - a handler bug must not take the link down
                self.counters.rx_malformed += 1
                log.exception("MAVLink %s: handling %s failed", self.url, msg.get_type())

    def _on_stream_closed(self) -> None:
        self.counters.reconnects += 1
        if self.kind == "tcpin":
            log.info("MAVLink %s: client disconnected", self.url)
            try:
                self.conn.port.close()
            except OSError:
                pass
            self.conn.port = None
            self.conn.fd = self.conn.listen.fileno()
            self._register_fd()
            return
        log.info("MAVLink %s: connection closed (peer gone or device unplugged); reconnecting", self.url)
        if self._fd is not None:
            self._loop.remove_reader(self._fd)
            self._fd = None
        self._drop_out_queue()
        try:
            self.conn.close()
        except OSError:
            pass
        self.conn = None
        self._connect_task = self._loop.create_task(self._connect_retrying())


def is_for_us(msg, system_id: int, component_id: int) -> tuple[bool, bool]:
    """MAVLink routing rule (mavlink.io en/guide/routing.md): (process it?, was it broadcast to all components?).

    Process when target_system is absent/0, or equals ours and target_component is absent/0 or ours.
    """
    # the target fields exist on the targeted message types only: pymavlink's messages declare no common set
    ts = getattr(msg, "target_system", 0)
    tc = getattr(msg, "target_component", 0)
    if ts not in (0, system_id):
        return False, False
    if tc == 0:
        return True, True
    return tc == component_id, False
