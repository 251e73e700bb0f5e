"""tests/support/udp_drops.py reads the kernel's count of datagrams dropped on a socket: checked against what was
sent and what was read (the truth, counted here), on a socket whose buffer is made too small to hold them."""

from __future__ import annotations

import socket

from support.udp_drops import port_drops, socket_drops, widen_receive_buffer


def _pair(rcvbuf: int | None):
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    if rcvbuf is not None:
        rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)    # the kernel's floor: a few datagrams
    rx.bind(("127.0.0.1", 0))
    rx.setblocking(False)
    return rx, socket.socket(socket.AF_INET, socket.SOCK_DGRAM)


def _read_all(rx) -> int:
    n = 0
    while True:
        try:
            rx.recv(2048)
        except BlockingIOError:
            return n
        n += 1


def test_what_was_sent_is_what_was_read_plus_what_the_kernel_dropped():
    rx, tx = _pair(rcvbuf=1)
    try:
        assert socket_drops(rx) == 0
        sent = 300
        for _ in range(sent):                        # loopback delivers within sendto: nothing in flight after
            tx.sendto(b"x" * 200, rx.getsockname())
        read = _read_all(rx)
        assert 0 < read < sent                       # the buffer held some, not all
        assert socket_drops(rx) == sent - read
        assert port_drops(rx.getsockname()[1]) == sent - read
    finally:
        rx.close()
        tx.close()


def test_a_widened_buffer_is_never_smaller_and_what_the_socket_reports():
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        before = rx.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
        got = widen_receive_buffer(rx)
        assert got == rx.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) >= before
    finally:
        rx.close()
