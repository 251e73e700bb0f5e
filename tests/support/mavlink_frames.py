"""CRC-valid MAVLink 2 frames with hostile contents, built from pymavlink's message definitions (the
ardupilotmega dialect the daemon speaks) — for structure-aware fuzzing.

The frame is assembled here, not by pymavlink's `pack`, so the test controls what pack would not send: a
payload cut anywhere (MAVLink 2 trims trailing zero bytes and a receiver zero-fills, so a short payload is a
legal frame whose last fields — the extensions first — read as 0), and a signature made with any key and
timestamp. Layout and CRC per the MAVLink 2 serialization spec: STX 0xFD, len, incompat_flags, compat_flags,
seq, sysid, compid, msgid (24 bit LE), payload, X.25 CRC over everything after STX plus the message's
CRC_EXTRA; signed (incompat bit 0): link_id, 48-bit timestamp, first 6 bytes of
SHA-256(key + header + payload + CRC + link_id + timestamp).
"""

from __future__ import annotations

import hashlib
import math
import struct
from collections import Counter
from dataclasses import dataclass
from functools import cache

from hypothesis import strategies as st

from ahrsd.daemon.mavlink_io import mavlink

STX_V2 = 0xFD
INCOMPAT_SIGNED = 0x01

INT_RANGES = {
    "int8_t": (-2**7, 2**7 - 1), "uint8_t": (0, 2**8 - 1), "int16_t": (-2**15, 2**15 - 1),
    "uint16_t": (0, 2**16 - 1), "int32_t": (-2**31, 2**31 - 1), "uint32_t": (0, 2**32 - 1),
    "int64_t": (-2**63, 2**63 - 1), "uint64_t": (0, 2**64 - 1), "uint8_t_mavlink_version": (0, 255),
}
HOSTILE_FLOATS = (math.nan, math.inf, -math.inf, 0.0, -0.0, 1.0, -1.0, 1e38, -1e38, 3.4028235e38,
                  -3.4028235e38, 1.4e-45, 2**31, -2**31 - 1.0, 16777217.0)


# Each strategy below is built once per argument (functools.cache): hypothesis validates a new strategy object
# and computes its label on its first draw, which was most of the fuzz tests' CPU when every example built its
# own (docs/testing.md "Where the suite's CPU goes"). The values each one can draw are the same.
@cache
def int_values(ctype: str):
    lo, hi = INT_RANGES[ctype]
    return st.one_of(st.sampled_from(sorted({lo, hi, 0, 1, lo + 1, hi - 1, -1 if lo < 0 else 2})),
                     st.integers(lo, hi))


@cache
def float_values(ctype: str):
    width = 64 if ctype == "double" else 32
    return st.one_of(st.sampled_from(HOSTILE_FLOATS), st.floats(width=width))


@cache
def char_values(n: int):
    """char[n]: shorter (NUL-terminated on the wire), exactly n (no NUL), NULs inside, non-ASCII bytes."""
    return st.one_of(st.binary(max_size=n), st.binary(min_size=n, max_size=n).map(lambda b: b.replace(b"\0", b"A")),
                     st.text(alphabet=st.characters(min_codepoint=32, max_codepoint=126), min_size=n,
                             max_size=n).map(str.encode))


@cache
def enum_values(enum_name: str, ctype: str):
    """An enum field: a defined value, the ENUM_END sentinel, or any value of the type."""
    defined = sorted(mavlink.enums.get(enum_name, {}))
    lo, hi = INT_RANGES.get(ctype, (0, 255))
    defined = [v for v in defined if lo <= v <= hi] or [0]
    return st.one_of(st.sampled_from(defined), int_values(ctype))


@dataclass(frozen=True)
class FieldDef:
    name: str
    ctype: str
    array_length: int          # 0: scalar
    enum: str | None


@cache
def message_fields(cls) -> tuple[FieldDef, ...]:
    """The fields of a pymavlink message class in wire order (ordered_fieldnames; array_lengths follow it)."""
    out = []
    for name, n in zip(cls.ordered_fieldnames, cls.array_lengths):
        ctype = cls.fieldtypes[cls.fieldnames.index(name)]
        out.append(FieldDef(name, ctype, n, cls.fieldenums_by_name.get(name)))
    return tuple(out)


def field_strategy(f: FieldDef, overrides: dict):
    if f.name in overrides:
        return overrides[f.name]
    return _field_values(f)


@cache
def _field_values(f: FieldDef):
    """The strategy of a field that is not overridden: its type's values (an array of them for an array)."""
    if f.ctype == "char":
        return char_values(max(1, f.array_length))
    if f.ctype in ("float", "double"):
        element = float_values(f.ctype)
    elif f.enum and f.array_length == 0:
        element = enum_values(f.enum, f.ctype)
    else:
        element = int_values(f.ctype)
    if f.array_length:
        return st.lists(element, min_size=f.array_length, max_size=f.array_length)
    return element


def encode_payload(cls, values: dict) -> bytes:
    """The full (untrimmed) payload of `cls` with `values` by field name, packed with the class's wire format."""
    flat = []
    for f in message_fields(cls):
        v = values[f.name]
        if f.array_length and f.ctype != "char":
            flat.extend(v)
        else:
            flat.append(v)
    return cls.unpacker.pack(*flat)


def frame(msg_id: int, crc_extra: int, payload: bytes, *, seq: int, sysid: int, compid: int,
          sign: tuple[bytes, int, int] | None = None) -> bytes:
    """A MAVLink 2 frame; `sign` = (key, link_id, timestamp) adds a signature."""
    incompat = INCOMPAT_SIGNED if sign else 0
    header = bytes([STX_V2, len(payload), incompat, 0, seq & 0xFF, sysid, compid]) + msg_id.to_bytes(3, "little")
    crc = mavlink.x25crc(header[1:] + payload)
    crc.accumulate(bytes([crc_extra]))
    out = header + payload + struct.pack("<H", crc.crc)
    if sign:
        key, link_id, timestamp = sign
        tail = bytes([link_id]) + timestamp.to_bytes(6, "little")
        out += tail + hashlib.sha256(key + out + tail).digest()[:6]
    return out


class FrameLog:
    """Frames generated per message type, for the summary the fuzz tests print."""

    def __init__(self):
        self.by_type: Counter = Counter()
        self.signed: Counter = Counter()
        self.truncated = 0
        self.acks: Counter = Counter()       # (command, MAV_RESULT name) of the COMMAND_ACKs the frames got

    def summary(self) -> str:
        lines = [f"{sum(self.by_type.values())} CRC-valid frames of {len(self.by_type)} message types "
                 f"({self.truncated} with a cut payload; signing: {dict(self.signed)})"]
        for name, n in sorted(self.by_type.items(), key=lambda kv: (-kv[1], kv[0])):
            lines.append(f"  {name:32s} {n}")
        return "\n".join(lines)


_PAYLOAD_FORM = st.sampled_from(["trimmed", "trimmed", "full", "cut"])


@st.composite
def message_payloads(draw, cls, overrides: dict | None = None):
    """(values by field name, payload bytes — full length or cut short) for message class `cls`."""
    overrides = overrides or {}
    values = {f.name: draw(field_strategy(f, overrides)) for f in message_fields(cls)}
    payload = encode_payload(cls, values)
    how = draw(_PAYLOAD_FORM)
    if how == "trimmed":                         # what a MAVLink 2 sender puts on the wire
        payload = payload.rstrip(b"\0") or payload[:1]
    elif how == "cut":                           # shorter still: later fields (extensions first) read as 0
        payload = payload[: draw(st.integers(1, len(payload)))]
    return values, payload, how == "cut"


def extreme_values(cls, which: str, overrides: dict | None = None) -> dict:
    """Every field of `cls` at one extreme: "max" (integers at their maximum, floats NaN, char ids filling
    the array without a NUL) or "min" (integers at their minimum, floats −inf, empty strings)."""
    out = {}
    for f in message_fields(cls):
        if f.ctype == "char":
            v = b"A" * max(1, f.array_length) if which == "max" else b""
        elif f.ctype in ("float", "double"):
            v = math.nan if which == "max" else -math.inf
        else:
            lo, hi = INT_RANGES[f.ctype]
            v = hi if which == "max" else lo
        if f.array_length and f.ctype != "char":
            v = [v] * f.array_length
        out[f.name] = v
    out.update(overrides or {})
    return out


def sweep_payloads(overrides: dict | None = None):
    """(message name, class, payload) for every message of the dialect: all fields at their maximum, all at
    their minimum, and the maximum cut to its first byte. `overrides` (field name → value) applies to every
    message with that field (e.g. the target ids, so that the frames are addressed to the daemon)."""
    for cls in sorted(mavlink.mavlink_map.values(), key=lambda c: c.id):
        names = set(cls.fieldnames)
        fixed = {k: v for k, v in (overrides or {}).items() if k in names}
        top = encode_payload(cls, extreme_values(cls, "max", fixed))
        yield cls.msgname, cls, top
        yield cls.msgname, cls, encode_payload(cls, extreme_values(cls, "min", fixed))
        yield cls.msgname, cls, top[:1]
