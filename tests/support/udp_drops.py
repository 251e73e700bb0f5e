"""The kernel's count of datagrams dropped on a socket (ahrsd.core.udp_drops, for a socket object), and
`widen_receive_buffer`: ask for a larger receive buffer (the kernel caps it at net.core.rmem_max without
CAP_NET_ADMIN, socket(7)), so that drops are rare; the count is what makes a test hold when they happen."""

from __future__ import annotations

import socket

from ahrsd.core import udp_drops
from ahrsd.core.udp_drops import port_drops

__all__ = ["port_drops", "socket_drops", "widen_receive_buffer"]


def socket_drops(sock: socket.socket) -> int:
    """Datagrams the kernel dropped on this socket of ours since it was made."""
    return udp_drops.socket_drops(sock.fileno())


def widen_receive_buffer(sock: socket.socket, want_bytes: int = 4 << 20) -> int:
    """Ask for a receive buffer of `want_bytes` (capped by the kernel at net.core.rmem_max); returns what the
    socket has now (the kernel doubles the request for its bookkeeping, socket(7) SO_RCVBUF)."""
    if sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) < want_bytes:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, want_bytes)
    return sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
