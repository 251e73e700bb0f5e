"""The frame daemon.mavlink_frame packs is the one pymavlink packs (`MAVLink_message.pack`, the independent
implementation the daemon used before): every message class of the dialect with random fields, payloads that end
in zeros or are all zeros, sequence numbers and ids across their range; and an endpoint sends those bytes and
moves pymavlink's sequence and counters as `MAVLink.send` does, a signed link still signing."""

from __future__ import annotations

import asyncio
import socket

import numpy as np
import pytest

from ahrsd.daemon.mavlink_frame import FramePacker
from ahrsd.daemon.mavlink_io import Endpoint, mavlink

INT_RANGES = {"int8_t": (-128, 127), "uint8_t": (0, 255), "int16_t": (-32768, 32767), "uint16_t": (0, 65535),
              "int32_t": (-2**31, 2**31 - 1), "uint32_t": (0, 2**32 - 1), "int64_t": (-2**63, 2**63 - 1),
              "uint64_t": (0, 2**64 - 1)}


def _value(rng, ftype: str, length: int, zeros: bool):
    """A random field value of a pymavlink field (`zeros`: mostly zeros, so payloads end in zero bytes)."""
    def one():
        if zeros and rng.random() < 0.8:
            return 0.0 if ftype in ("float", "double") else 0
        if ftype in ("float", "double"):
            return float(np.float32(rng.normal(0.0, 100.0))) if ftype == "float" else float(rng.normal(0.0, 1e6))
        lo, hi = INT_RANGES[ftype]
        return int(rng.integers(lo, hi, endpoint=True, dtype=np.int64 if ftype != "uint64_t" else np.uint64))
    if ftype == "char":
        n = 0 if zeros else int(rng.integers(0, max(1, length) + 1))
        return bytes(rng.integers(32, 127, n).astype(np.uint8))
    if length:
        return [one() for _ in range(length)]
    return one()


def _random_message(cls, rng, zeros: bool = False):
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths))
    return cls(*[_value(rng, ftype, lengths[name], zeros) for name, ftype in zip(cls.fieldnames, cls.fieldtypes)])


def _pymavlink_frame(msg, seq: int, system_id: int, component_id: int) -> bytes:
    mav = mavlink.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
    mav.seq = seq
    return bytes(msg.pack(mav))


@pytest.mark.parametrize("zeros", [False, True])
def test_every_message_of_the_dialect_packs_to_pymavlinks_bytes(zeros):
    rng = np.random.default_rng(39)
    packer = FramePacker()
    classes = sorted(mavlink.mavlink_map.values(), key=lambda c: c.id)
    assert len(classes) > 200
    for cls in classes:
        for _ in range(3):
            msg = _random_message(cls, rng, zeros)
            seq, sysid, compid = (int(v) for v in rng.integers(0, 256, 3))
            assert packer.frame(msg, seq, sysid, compid) == _pymavlink_frame(msg, seq, sysid, compid), cls.msgname


def test_an_all_zero_payload_keeps_one_byte_and_the_outputs_fields_pack_as_pymavlink_does():
    packer = FramePacker()
    hb = mavlink.MAVLink_heartbeat_message(0, 0, 0, 0, 0, 0)
    frame = packer.frame(hb, 255, 1, 197)
    assert frame == _pymavlink_frame(hb, 255, 1, 197) and frame[1] == 1 and len(frame) == 10 + 1 + 2
    vpe = mavlink.MAVLink_vision_position_estimate_message(2**63 + 5, 0.0, 0.0, 0.0, 0.1, -0.2, 3.1,
                                                           [float(k) for k in range(21)], 255)
    assert packer.frame(vpe, 7, 42, 197) == _pymavlink_frame(vpe, 7, 42, 197)
    chunk = mavlink.MAVLink_statustext_message(6, b"", 12, 3)        # a STATUSTEXT's empty last chunk
    assert packer.frame(chunk, 0, 1, 197) == _pymavlink_frame(chunk, 0, 1, 197)


def _link(signing_key: bytes | None = None):
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(2.0)
    ep = Endpoint(f"udpout:127.0.0.1:{rx.getsockname()[1]}", 42, 197, lambda _ep, _msg: None)
    ep.open(asyncio.new_event_loop())
    if signing_key is not None:
        ep.enable_signing(signing_key, 3, 1_000_000, lambda _mav, _id: True)
    return ep, rx


def test_an_endpoint_sends_pymavlinks_frames_with_its_sequence_and_counts_as_pymavlink_does():
    ep, rx = _link()
    logged = []
    ep.traffic_log = logged.append
    rng = np.random.default_rng(5)
    try:
        ep.conn.mav.seq = 250                                   # wraps at 256
        sent = [_random_message(mavlink.MAVLink_attitude_message, rng) for _ in range(10)]
        for k, msg in enumerate(sent):
            assert ep.send(msg)
            want = _pymavlink_frame(msg, (250 + k) % 256, 42, 197)
            assert rx.recv(65535) == want and bytes(logged[-1]) == want
        mav = ep.conn.mav
        assert (mav.seq, mav.total_packets_sent, ep.counters.tx_messages) == (4, 10, 10)
        assert mav.total_bytes_sent == sum(len(b) for b in logged)
    finally:
        ep.close()
        ep._loop.close()
        rx.close()


def test_a_signed_link_still_signs_every_frame():
    ep, rx = _link(b"k" * 32)
    try:
        assert ep.send(mavlink.MAVLink_attitude_message(1, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0))
        data = rx.recv(65535)
        assert data[2] & mavlink.MAVLINK_IFLAG_SIGNED and len(data) == 10 + data[1] + 2 + 13
    finally:
        ep.close()
        ep._loop.close()
        rx.close()
