"""Where NMEA 0183 sentences go: a UDP datagram per sentence (unicast or broadcast), a TCP server that any
number of clients join (OpenCPN, Signal K, kplex, a plotter's Wi-Fi gateway), or a serial port.

Every transport's `send(data) -> bool` never blocks and never raises: a sentence that cannot go out now (a full
socket buffer, a client that reads too slowly, a serial line that is behind) is dropped and counted. A heading
sentence is stale after 0.1 s, so a queue that grows would only deliver old headings later.
"""

from __future__ import annotations

import asyncio
import logging
import socket
from dataclasses import dataclass

log = logging.getLogger(__name__)

TCP_CLIENT_BUFFER_LIMIT_BYTES = 4096    # a client further behind than this misses sentences (it is too slow)
TCP_SOCKET_SEND_BUFFER_BYTES = 16384    # and the kernel holds no more than this for it: a live stream, not a queue
SERIAL_BACKLOG_LIMIT_BYTES = 256        # the serial driver's output queue beyond which sentences are dropped


@dataclass
class TransportCounters:
    sent: int = 0          # sentences handed to the operating system (per client for TCP)
    dropped: int = 0       # sentences not sent: buffer full, client too slow, line behind
    errors: int = 0        # send failures (no route, device gone)
    clients: int = 0       # TCP: connected now

    def as_dict(self) -> dict:
        return dict(vars(self))


def _host_port(url: str) -> tuple[str, int]:
    host, _, port = url.split(":", 1)[1].rpartition(":")
    return host or "0.0.0.0", int(port)


class UdpTransport:
    """One datagram per sentence (NMEA 0183 over UDP as IEC 61162-450's predecessors and OpenCPN take it)."""

    def __init__(self, url: str):
        self.description = url
        self.address = _host_port(url)
        self.counters = TransportCounters()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        if url.startswith("udpbcast:"):
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
        self.sock.setblocking(False)

    def open(self, loop: asyncio.AbstractEventLoop) -> None:
        return None

    def send(self, data: bytes) -> bool:
        try:
            self.sock.sendto(data, self.address)
        except BlockingIOError:
            self.counters.dropped += 1
            return False
        except OSError as exc:
            self.counters.errors += 1
            if self.counters.errors == 1:
                log.warning("NMEA output %s: %s", self.description, exc)
            return False
        self.counters.sent += 1
        return True

    def close(self) -> None:
        self.sock.close()


class TcpServerTransport:
    """A listening socket; every connected client gets every sentence. Clients that stop reading lose
    sentences (counted), never the others' and never the daemon's time."""

    def __init__(self, url: str):
        self.description = url
        self.host, self.port = _host_port(url)
        self.counters = TransportCounters()
        self._server: asyncio.AbstractServer | None = None
        self._serving: asyncio.Task | None = None
        self._clients: set[asyncio.StreamWriter] = set()

    def open(self, loop: asyncio.AbstractEventLoop) -> None:
        """Bind now (a port in use is an error at start, naming the output), serve on the loop."""
        sock = self._listening_socket()
        sock.setblocking(False)
        self.port = sock.getsockname()[1]          # the real port when 0 was asked for
        self._serving = loop.create_task(self._serve(sock), name=f"nmea {self.description}")

    def _listening_socket(self) -> socket.socket:
        """The socket bound and listening; OSError naming the output when the address cannot be had."""
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((self.host, self.port))
            sock.listen(8)
        except OSError as exc:
            sock.close()
            raise OSError(f"NMEA output {self.description}: cannot listen on {self.host}:{self.port}: "
                          f"{exc.strerror or exc}") from None
        return sock

    async def _serve(self, sock: socket.socket) -> None:
        self._server = await asyncio.start_server(self._on_client, sock=sock)

    async def _on_client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        sock = writer.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, TCP_SOCKET_SEND_BUFFER_BYTES)
        self._clients.add(writer)
        self.counters.clients = len(self._clients)
        try:
            while await reader.read(1024):      # clients may talk (e.g. a keep-alive); nothing is expected
                pass
        except (ConnectionError, OSError, asyncio.CancelledError):   # cancelled: the server is closing
            pass
        finally:
            self._clients.discard(writer)
            self.counters.clients = len(self._clients)
            writer.close()

    def send(self, data: bytes) -> bool:
        delivered = False
        for writer in list(self._clients):
            if writer.is_closing():
                self._clients.discard(writer)
                continue
            if writer.transport.get_write_buffer_size() > TCP_CLIENT_BUFFER_LIMIT_BYTES:
                self.counters.dropped += 1
                continue
            writer.write(data)
            self.counters.sent += 1
            delivered = True
        self.counters.clients = len(self._clients)
        return delivered

    def close(self) -> None:
        for writer in list(self._clients):
            writer.close()
        self._clients.clear()
        if self._server is not None:
            self._server.close()
        if self._serving is not None:
            self._serving.cancel()


class SerialTransport:
    """A serial port (RS-422 for NMEA 0183 listeners through a USB adapter, or RS-232), 8N1."""

    def __init__(self, url: str):
        import serial          # pyserial; a dependency

        self.description = url
        device, _, baud = url[len("serial:"):].partition(",")
        self.device = device
        self.baud = int(baud) if baud else 4800
        self.counters = TransportCounters()
        try:
            self.port = serial.Serial(device, self.baud, write_timeout=0)
        except (serial.SerialException, OSError) as exc:
            raise OSError(f"NMEA output {url}: cannot open {device}: {exc}") from None

    def open(self, loop: asyncio.AbstractEventLoop) -> None:
        return None

    def send(self, data: bytes) -> bool:
        try:
            if self.port.out_waiting > SERIAL_BACKLOG_LIMIT_BYTES:
                self.counters.dropped += 1
                return False
            written = self.port.write(data) or 0
        except Exception as exc:                # pyserial raises SerialException/SerialTimeoutException/OSError
            self.counters.errors += 1
            if self.counters.errors == 1:
                log.warning("NMEA output %s: %s", self.description, exc)
            return False
        if written < len(data):
            self.counters.dropped += 1
            return False
        self.counters.sent += 1
        return True

    def close(self) -> None:
        self.port.close()


def check_nmea_output_opens(url: str) -> None:
    """Bind and close what a `tcpserver:` output will listen on, so that an address the daemon cannot have is
    refused before the estimator's compile (OSError naming the output). UDP outputs bind nothing; a serial port is
    opened by the daemon, which says why when it cannot."""
    if url.startswith("tcpserver:"):
        TcpServerTransport(url)._listening_socket().close()


def open_transport(url: str):
    """The transport for an `[[nmea]] url` (validated by daemon.config)."""
    if url.startswith(("udp:", "udpbcast:")):
        return UdpTransport(url)
    if url.startswith("tcpserver:"):
        return TcpServerTransport(url)
    if url.startswith("serial:"):
        return SerialTransport(url)
    raise ValueError(f"not an NMEA output URL: {url!r}")
