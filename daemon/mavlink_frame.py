"""The unsigned MAVLink 2 frame of a pymavlink message, packed in one call: the bytes pymavlink's `MAVLink.send`
writes (`MAVLink_message._pack`), without the objects it makes on the way.

pymavlink packs a message through its header object, the header's own pack, a CRC object fed twice and a few
bytearray copies: some ten Python calls a message, which the daemon pays for every output it sends (100 a second
with the default outputs). Here each message class's payload is packed by its own `struct.Struct` (the class's
`unpacker`) from its fields in wire order (`ordered_fieldnames`; a numeric array field spread into its elements,
a char array packed from its bytes, as the generated `pack` methods do), trailing zero bytes trimmed down to one
(MAVLink 2 payload truncation), and the CRC-16/MCRF4XX over the header after the magic byte, the payload and the
message's CRC_EXTRA (mavlink.io "Serialization"; pymavlink uses the same `fastcrc` function when it is installed).
Signed frames are left to pymavlink (daemon.mavlink_io). tests/test_mavlink_frame.py holds the bytes equal to
pymavlink's for every message the daemon sends."""

from __future__ import annotations

import operator
import struct

from fastcrc.crc16 import mcrf4xx

MAGIC_V2 = 253
_HEADER = struct.Struct("<BBBBBBBHB")          # magic, len, incompat, compat, seq, sysid, compid, msgid (24 bits)


def _payload_packer(msg):
    """payload(msg) -> bytes for the pymavlink message class of `msg`: its fields in wire order into its struct. A
    char array is packed from the bytes pymavlink keeps for it (`_NAME_raw`, the field itself being decoded text)."""
    cls = type(msg)
    wire_types = _wire_types(cls)
    names = tuple(f"_{n}_raw" if t == "char" and hasattr(msg, f"_{n}_raw") else n
                  for n, t in zip(cls.ordered_fieldnames, wire_types))
    pack = cls.unpacker.pack
    spread = [n for n, length, ftype in zip(names, cls.array_lengths, wire_types) if length and ftype != "char"]
    if not spread:
        get = operator.attrgetter(*names)
        if len(names) == 1:
            return lambda msg: pack(get(msg))
        return lambda msg: pack(*get(msg))
    spread_set = frozenset(spread)

    def payload(msg) -> bytes:
        values = []
        for name in names:
            v = getattr(msg, name)
            if name in spread_set:
                values.extend(v)
            else:
                values.append(v)
        return pack(*values)
    return payload


def _wire_types(cls) -> list[str]:
    """The field types in wire order (`fieldtypes` lists them in the XML's order; `orders` maps one to the other)."""
    return [cls.fieldtypes[cls.fieldnames.index(name)] for name in cls.ordered_fieldnames]


class FramePacker:
    """`frame(msg, seq, system_id, component_id) -> bytes`, the unsigned MAVLink 2 frame; a class's payload
    packer is made at its first message."""

    def __init__(self):
        self._by_class: dict[type, tuple] = {}

    def frame(self, msg, seq: int, system_id: int, component_id: int) -> bytes:
        entry = self._by_class.get(type(msg))
        if entry is None:
            cls = type(msg)
            entry = self._by_class[cls] = (_payload_packer(msg), cls.id & 0xFFFF, cls.id >> 16,
                                           bytes((cls.crc_extra,)))
        payload_of, id_low, id_high, crc_extra = entry
        payload = payload_of(msg)
        n = len(payload.rstrip(b"\0")) or 1         # trailing zeros trimmed, at least one byte kept
        if n < len(payload):
            payload = payload[:n]
        body = _HEADER.pack(MAGIC_V2, n, 0, 0, seq, system_id, component_id, id_low, id_high) + payload
        crc = mcrf4xx(crc_extra, mcrf4xx(memoryview(body)[1:], 0xFFFF))
        return body + crc.to_bytes(2, "little")
