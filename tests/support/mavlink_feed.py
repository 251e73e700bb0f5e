"""Driving an in-process daemon (tests/service_rig.py) over its real receive path: one datagram in through the
endpoint's parser and dispatch, and every message the daemon sent to the GCS socket out."""

from __future__ import annotations

import asyncio

from ahrsd.daemon.mavlink_io import mavlink


def drain(rig) -> list:
    """Run pending loop callbacks, then every message the daemon sent to the GCS socket."""
    rig.loop.run_until_complete(asyncio.sleep(0))
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    out = []
    while True:
        try:
            data = rig.gcs.recv(65536)
        except BlockingIOError:
            return out
        out += [m for m in parser.parse_buffer(data) or () if m.get_type() != "BAD_DATA"]


def feed(rig, data: bytes) -> None:
    """One datagram through the endpoint's parser and dispatch, as the event loop would deliver it."""
    rig.ep._parse(data)
    rig.ep._end_of_datagram()


def as_if_from(msg, sysid: int = 1, compid: int = 1):
    """`msg` with the sender header a parsed message from (sysid, compid) carries, for handing straight to the
    daemon's dispatch (pymavlink sets it only when it parses or packs)."""
    msg._header = mavlink.MAVLink_header(msg.id, srcSystem=sysid, srcComponent=compid)
    return msg
