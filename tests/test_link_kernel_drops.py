"""A UDP link counts what the kernel dropped on its socket (`rx_dropped_by_kernel`, core.udp_drops): the
datagrams sent to it while the daemon did not read (a stall) that did not fit its receive buffer. Truth counted
here: what was sent, and what the link's handler got once the loop ran again."""

from __future__ import annotations

import asyncio
import socket

from ahrsd.daemon.mavlink_io import Endpoint, mavlink


def test_a_stalled_udp_link_counts_what_the_kernel_dropped():
    async def scenario():
        loop = asyncio.get_running_loop()
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            probe.bind(("127.0.0.1", 0))
            port = probe.getsockname()[1]
        got = []
        ep = Endpoint(f"udpin:127.0.0.1:{port}", 1, 200, lambda e, m: got.append(m))
        ep.open(loop)
        ep.conn.port.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1)    # the kernel's floor: a few datagrams
        sender = mavlink.MAVLink(None, srcSystem=9, srcComponent=1)
        sent = 300
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for _ in range(sent):              # the loop does not run meanwhile: the daemon "stalls"
                s.sendto(sender.heartbeat_encode(2, 3, 0, 0, 4).pack(sender), ("127.0.0.1", port))
        for _ in range(20):                    # now it reads what the buffer held
            await asyncio.sleep(0.01)
        ep.close()
        return sent, len(got), ep.counters

    sent, read, counters = asyncio.run(scenario())
    assert 0 < read < sent                     # the buffer held some, not all
    assert counters.rx_messages == read
    assert counters.rx_dropped_by_kernel == sent - read
