"""The byte budget of a serial link: what the configured outputs need, against what the line can carry.

A UART with 8N1 framing carries baud/10 bytes per second (start bit + 8 data bits + stop bit). A MAVLink 2
frame is 10 header bytes + payload + 2 CRC bytes, + 13 when signed (link id, 48-bit timestamp, 48-bit
signature; MAVLink 2 signing, mavlink devguide message_signing.md). MAVLink 2 trims trailing zero bytes of the
payload, so the full payload length is the largest frame a message can take: the budget uses it, so the check
is an upper bound of what the outputs put on the wire.

The same priorities decide which messages a link that cannot keep up drops first (daemon.serial_queue):
0 is dropped last (VISION_POSITION_ESTIMATE, the heading the autopilot fuses, and HEARTBEAT, without which
routers and ground stations lose us), higher numbers first.
"""

from __future__ import annotations

from dataclasses import dataclass

from ahrsd.daemon.mavlink_io import mavlink, max_frame_bytes
from ahrsd.daemon.output_registry import BY_MESSAGE_ID

BITS_PER_BYTE_8N1 = 10
WARN_FRACTION = 0.8                 # warn above 80 % of the line's byte rate
HEARTBEAT_HZ = 1.0
HEARTBEAT_PRIORITY = 0
EVENT_PRIORITY = 1                  # answers and session traffic: COMMAND_ACK, PARAM_VALUE, STATUSTEXT, MAG_CAL_*


def priority_of(message_id: int) -> int:
    if message_id == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
        return HEARTBEAT_PRIORITY
    spec = BY_MESSAGE_ID.get(message_id)
    return EVENT_PRIORITY if spec is None else spec.priority


def line_bytes_per_s(baud: int) -> float:
    return baud / BITS_PER_BYTE_8N1


@dataclass(frozen=True)
class StreamLoad:
    message_id: int
    rate_hz: float
    bytes_per_s: float

    @property
    def name(self) -> str:
        return mavlink.mavlink_map[self.message_id].msgname


def stream_loads(rates_hz: dict[int, float], signed: bool = False) -> list[StreamLoad]:
    """Bytes per second of each stream that is on (HEARTBEAT included), largest first."""
    loads = [StreamLoad(mavlink.MAVLINK_MSG_ID_HEARTBEAT, HEARTBEAT_HZ,
                        HEARTBEAT_HZ * max_frame_bytes(mavlink.MAVLINK_MSG_ID_HEARTBEAT, signed))]
    loads += [StreamLoad(mid, hz, hz * max_frame_bytes(mid, signed)) for mid, hz in rates_hz.items() if hz > 0.0]
    return sorted(loads, key=lambda s: -s.bytes_per_s)


def budget_message(url: str, baud: int, rates_hz: dict[int, float], signed: bool) -> tuple[float, str]:
    """(fraction of the line used, a one-paragraph report naming the figures and what to lower)."""
    loads = stream_loads(rates_hz, signed)
    total = sum(s.bytes_per_s for s in loads)
    capacity = line_bytes_per_s(baud)
    fraction = total / capacity
    # what to lower: the largest streams the autopilot does not need (loads is sorted largest first)
    lowerable = [s for s in loads if priority_of(s.message_id) > 0]
    hints = ", ".join(f"{s.name} ({s.rate_hz:g} Hz, {s.bytes_per_s:.0f} B/s)" for s in lowerable[:4])
    text = (f"MAVLink {url}: the outputs need {total:.0f} B/s{' (signed)' if signed else ''}, "
            f"{100 * fraction:.0f} % of the line ({capacity:.0f} B/s at {baud} baud, 8N1)")
    if fraction > WARN_FRACTION:
        text += (f"; above {100 * WARN_FRACTION:.0f} %: lower {hints or 'the rates'} with [[endpoint]] outputs "
                 f"or profile = \"autopilot\", or raise the baud rate; when the port cannot keep up the "
                 f"lowest-priority messages are dropped first")
    return fraction, text


class LinkBudget:
    """Checks one serial endpoint at start and after every rate change; warns once per excursion above
    WARN_FRACTION (again only after the load has come back under it)."""

    def __init__(self, url: str, baud: int):
        self.url = url
        self.baud = baud
        self.over = False
        self.fraction = 0.0
        self.warnings = 0

    def check(self, rates_hz: dict[int, float], signed: bool) -> str | None:
        """The warning text when the load has just gone above the threshold, else None."""
        self.fraction, text = budget_message(self.url, self.baud, rates_hz, signed)
        was_over, self.over = self.over, self.fraction > WARN_FRACTION
        if self.over and not was_over:
            self.warnings += 1
            return text
        return None
