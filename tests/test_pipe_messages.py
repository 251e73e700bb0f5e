"""The daemon reads the reader process's pipe raw (drivers.pipe_messages): the messages must be those
multiprocessing's Connection sends, whole and in order, however the pipe cuts them, and a look must read the pipe
once (what the raw read is for)."""

from __future__ import annotations

import multiprocessing
import os
import struct

import pytest

from ahrsd.drivers import pipe_messages
from ahrsd.drivers.pipe_messages import PipeMessages


def _pair():
    daemon_end, child_end = multiprocessing.Pipe()
    return daemon_end, child_end, PipeMessages(daemon_end.fileno())


def _all(messages: PipeMessages) -> list[bytes]:
    out, data = [], messages.next()
    while data is not None:
        out.append(bytes(data))
        data = messages.next(read=False)
    return out


def test_the_messages_of_connection_send_bytes_whole_and_in_order():
    daemon_end, child_end, messages = _pair()
    assert messages.next() is None                           # nothing there: no wait
    sent = [b"S" + bytes(range(120)) * k for k in (1, 3, 0, 12)] + [b"\x80pickle"]
    for m in sent:
        child_end.send_bytes(m)
    assert _all(messages) == sent
    assert messages.next() is None


def test_a_message_cut_by_the_pipe_waits_for_its_rest():
    """Bytes written by hand in three pieces, the cuts inside the header and inside the body."""
    daemon_end, child_end, messages = _pair()
    body = bytes(range(200))
    frame = struct.pack("!i", len(body)) + body + struct.pack("!i", 3) + b"abc"
    fd = child_end.fileno()
    os.write(fd, frame[:2])
    assert messages.next() is None
    os.write(fd, frame[2:100])
    assert messages.next() is None
    os.write(fd, frame[100:])
    assert _all(messages) == [body, b"abc"]


def test_more_than_one_read_holds_is_read_in_the_same_look(monkeypatch):
    monkeypatch.setattr(PipeMessages, "READ_BYTES", 1000)
    daemon_end, child_end, messages = _pair()
    sent = [bytes([k]) * 700 for k in range(5)]
    for m in sent:
        child_end.send_bytes(m)
    assert _all(messages) == sent


def test_the_other_end_closed_is_an_eof():
    daemon_end, child_end, messages = _pair()
    child_end.send_bytes(b"last")
    child_end.close()
    assert bytes(messages.next()) == b"last"
    with pytest.raises(EOFError):
        messages.next()


def test_a_look_reads_the_pipe_once(monkeypatch):
    """Three messages waiting: one read takes them all; the look's end reads nothing more (Connection's way was
    a poll, two reads a message and a last poll)."""
    reads = []
    real_read = os.read

    def counting_read(fd, n):
        reads.append(n)
        return real_read(fd, n)

    daemon_end, child_end, messages = _pair()
    for m in (b"a", b"bb", b"ccc"):
        child_end.send_bytes(m)
    monkeypatch.setattr(pipe_messages.os, "read", counting_read)
    assert _all(messages) == [b"a", b"bb", b"ccc"]
    assert len(reads) == 1

