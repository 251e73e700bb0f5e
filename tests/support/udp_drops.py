"""What the kernel dropped on a UDP socket: the `drops` column of /proc/net/udp and /proc/net/udp6 (the socket's
sk_drops, net/ipv4/udp.c udp4_format_sock), counted from the socket's creation. A datagram that finds the
socket's receive buffer full is dropped there and counted; a test that reads what a daemon sent can then tell
"the daemon did not send it" from "it was sent and this machine dropped it on the way in" (a test process
starved of the CPU on a loaded machine does not read in time).

And `widen_receive_buffer`: ask for a larger receive buffer (the kernel caps it at net.core.rmem_max without
CAP_NET_ADMIN, socket(7)), so that drops are rare; the count is what makes a test hold when they happen."""

from __future__ import annotations

import os
import socket
from pathlib import Path

_TABLES = (Path("/proc/net/udp"), Path("/proc/net/udp6"))
_LOCAL, _INODE, _DROPS = 1, 9, 12      # columns: sl local_address rem_address st tx:rx tr:when retrnsmt uid timeout
#                                        inode ref pointer drops


def _rows():
    for table in _TABLES:
        try:
            lines = table.read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            cols = line.split()
            if len(cols) > _DROPS:
                yield cols


def socket_drops(sock: socket.socket) -> int:
    """Datagrams the kernel dropped on this socket of ours since it was made (matched by its inode)."""
    inode = str(os.fstat(sock.fileno()).st_ino)
    for cols in _rows():
        if cols[_INODE] == inode:
            return int(cols[_DROPS])
    raise LookupError(f"socket inode {inode} not in {', '.join(map(str, _TABLES))}")


def port_drops(port: int) -> int:
    """Datagrams the kernel dropped on the UDP socket(s) bound to local `port` (another process's socket,
    e.g. a daemon's udpout link): the sum over the sockets on that port."""
    suffix = f":{port:04X}"
    return sum(int(cols[_DROPS]) for cols in _rows() if cols[_LOCAL].endswith(suffix))


def widen_receive_buffer(sock: socket.socket, want_bytes: int = 4 << 20) -> int:
    """Ask for a receive buffer of `want_bytes` (capped by the kernel at net.core.rmem_max); returns what the
    socket has now (the kernel doubles the request for its bookkeeping, socket(7) SO_RCVBUF)."""
    if sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) < want_bytes:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, want_bytes)
    return sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
