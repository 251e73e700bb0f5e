"""What the kernel dropped on a UDP socket: the `drops` column of /proc/net/udp and /proc/net/udp6 (the socket's
sk_drops, net/ipv4/udp.c udp4_format_sock), counted from the socket's creation. A datagram that finds the
socket's receive buffer full is dropped there and counted: a daemon stalled for a moment (a loaded machine)
loses what its peers sent meanwhile before it can read it, and only the kernel can say how many
(daemon.mavlink_io: a UDP link's `rx_dropped_by_kernel`); a test that reads what a daemon sent can tell "the daemon
did not send it" from "it was sent and this machine dropped it on the way in"."""

from __future__ import annotations

import os
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


def socket_drops(fileno: int) -> int:
    """Datagrams the kernel dropped on the UDP socket open as `fileno` in this process since it was made (matched
    by its inode); LookupError when no UDP table lists it (not a UDP socket, or no /proc)."""
    inode = str(os.fstat(fileno).st_ino)
    for cols in _rows():
        if cols[_INODE] == inode:
            return int(cols[_DROPS])
    raise LookupError(f"socket inode {inode} not in {', '.join(map(str, _TABLES))}")


def port_drops(port: int) -> int:
    """Datagrams the kernel dropped on the UDP socket(s) bound to local `port` (another process's socket,
    e.g. a daemon's udpout link): the sum over the sockets on that port."""
    suffix = f":{port:04X}"
    return sum(int(cols[_DROPS]) for cols in _rows() if cols[_LOCAL].endswith(suffix))
