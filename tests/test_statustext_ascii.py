"""STATUSTEXT is ASCII on the wire: a ground station decodes `char[50]` as ASCII, so "±0.3°" must arrive as
"+-0.3 deg", not as the UTF-8 bytes MAVProxy showed as "(��0.3��)"."""

from __future__ import annotations

from ahrsd.daemon.counters import ServiceCounters
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.messages import statustext_chunks
from ahrsd.daemon.outbound import Identity, Outbound
from ahrsd.daemon.statustext_ascii import statustext_ascii
from support.kept_link import KeptLink

MAV = mavlink.MAVLink(None, srcSystem=1, srcComponent=200)


def on_the_wire(msg) -> bytes:
    """The text bytes a ground station receives (parsed back from the packed frame)."""
    frame = bytes(mavlink.MAVLink(None).parse_char(bytearray(msg.pack(MAV))).get_msgbuf())
    payload = frame[10:10 + frame[1]]           # MAVLink 2: 10-byte header, payload length in byte 1
    return payload[1:51].rstrip(b"\0")          # severity, then text[50]


def test_symbols_are_spelled_out_in_ascii():
    assert statustext_ascii("ahrsd: heading from magnetometer (±0.3°)") == \
        b"ahrsd: heading from magnetometer (+-0.3 deg)"
    assert statustext_ascii("hard iron 0.4 µT, σ 1.2°, 5 → 6, naïve") == b"hard iron 0.4 uT, sigma 1.2 deg, 5 -> 6, naive"
    assert statustext_ascii("mag vs GNSS 36 °") == b"mag vs GNSS 36 deg"
    assert statustext_ascii("漢") == b"?"


def test_single_statustext_is_ascii_on_the_wire():
    (msg,) = statustext_chunks(mavlink.MAV_SEVERITY_INFO, "ahrsd: heading from magnetometer (±0.3°)", 1)
    data = on_the_wire(msg)
    assert data == b"ahrsd: heading from magnetometer (+-0.3 deg)"
    data.decode("ascii")


def test_long_statustext_chunks_are_ascii_and_reassemble():
    link = KeptLink()
    outbound = Outbound(Identity(1, 200, mavlink.MAV_TYPE_IMU), ServiceCounters(), clock=lambda: 0.0)
    outbound.endpoints.append(link)
    sent = link.sent
    outbound.statustext(mavlink.MAV_SEVERITY_WARNING,
                        "ahrsd: heading reset to the GNSS yaw (±1.5°) after the magnetometer disagreed by 36°")
    text = b"".join(on_the_wire(m) for m in sent)
    assert text == b"ahrsd: heading reset to the GNSS yaw (+-1.5 deg) after the magnetometer disagreed by 36 deg"
    assert len(sent) == 2
    # every chunk decodes on its own (a multi-byte character is never cut in half at a 50-byte boundary)
    for m in statustext_chunks(6, "°" * 60, 1):
        on_the_wire(m).decode("ascii")
