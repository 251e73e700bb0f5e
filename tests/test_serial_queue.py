"""The serial output queue's admission (daemon.serial_queue) with worked numbers, on a pipe nobody reads: the
bytes it accepts wait in it, so its fill is exactly what it was given.

A line of 20 000 B/s and QUEUE_SECONDS = 0.1 s give a bound of 2000 bytes; priority p is admitted while the fill
after the frame stays within ADMIT_FRACTION[p] of it: 2000 B for 0 (VPE, HEARTBEAT), 1500 for 1, 1000 for 2,
500 for 3 and beyond. An empty queue takes any frame (a frame larger than its share is never starved)."""

from __future__ import annotations

import asyncio
import os
from types import SimpleNamespace

import pytest

from ahrsd.daemon.counters import ServiceCounters
from ahrsd.daemon.mavlink_io import Endpoint, LinkCounters, mavlink
from ahrsd.daemon.messages import statustext_chunks
from ahrsd.daemon.outbound import Identity, Outbound
from ahrsd.daemon.serial_queue import SerialOutQueue

LINE_B_S = 20_000.0
FRAME = b"\xfd" * 100


@pytest.fixture
def full_pipe():
    """A pipe's write end whose kernel buffer is full: nothing written to it leaves the queue."""
    r, w = os.pipe()
    os.set_blocking(w, False)
    for size in (4096, 1):
        while True:
            try:
                os.write(w, b"\0" * size)
            except BlockingIOError:
                break
    loop = asyncio.new_event_loop()
    yield w, loop
    loop.close()
    os.close(r)
    os.close(w)


def _offer(queue, priority, frames):
    queue.priority = priority
    return sum(queue.write(FRAME) == len(FRAME) for _ in range(frames))


def test_each_priority_is_admitted_up_to_its_share_of_the_bound(full_pipe):
    w, loop = full_pipe
    counters = LinkCounters()
    queue = SerialOutQueue(w, LINE_B_S, loop, counters)
    try:
        assert queue.capacity_bytes == 2000
        assert _offer(queue, 3, 10) == 5 and queue.waiting_bytes() == 500          # 500 B for priority 3
        assert _offer(queue, 2, 10) == 5 and queue.waiting_bytes() == 1000         # then up to 1000 for 2
        assert _offer(queue, 1, 10) == 5 and queue.waiting_bytes() == 1500
        assert _offer(queue, 0, 10) == 5 and queue.waiting_bytes() == 2000         # the heading fills the rest
        assert _offer(queue, 0, 1) == 0
        assert counters.tx_dropped == 5 + 5 + 5 + 5 + 1
        assert counters.tx_dropped_by_priority == {3: 5, 2: 5, 1: 5, 0: 6}
    finally:
        queue.close()


def test_an_empty_queue_takes_a_frame_larger_than_its_share(full_pipe):
    w, loop = full_pipe
    queue = SerialOutQueue(w, LINE_B_S, loop, LinkCounters())
    try:
        queue.priority = 3
        assert queue.write(b"\xfd" * 800) == 800 and queue.waiting_bytes() == 800
        assert queue.write(FRAME) == 0                                              # now it is over its share
    finally:
        queue.close()


def test_a_chunked_statustext_goes_whole_or_not_at_all_on_a_full_serial_link(full_pipe):
    """A serial endpoint at 5760 B/s (pymavlink writing into the queue, the line a full pipe): a 576-byte bound, 432
    for STATUSTEXT's priority 1. With 5 single texts (63-byte frames, 315 B) waiting, a 3-chunk text (frames of
    at most 66 B) would not fit whole: none of its chunks is sent, all 3 counted; sent one by one, the first chunk
    would have gone and the rest been refused: a cut text."""
    w, loop = full_pipe
    counters = LinkCounters()
    queue = SerialOutQueue(w, 5760.0, loop, counters)
    conn = SimpleNamespace(mav=mavlink.MAVLink(queue, srcSystem=1, srcComponent=200), fd=None)
    priority = [1]                                   # STATUSTEXT's (daemon.link_budget.EVENT_PRIORITY)
    ep = Endpoint("/dev/ttyAMA0,57600", 1, 200, lambda e, m: None, counters=counters, conn=conn,
                  priority_of=lambda message_id: priority[0], out_queue=queue)
    try:
        assert queue.capacity_bytes == 576
        for k in range(5):
            (single,) = statustext_chunks(mavlink.MAV_SEVERITY_INFO, f"ahrsd: {k}" + "x" * 42, 0)
            assert ep.send(single)
        assert queue.waiting_bytes() == 5 * 63
        chunks = statustext_chunks(mavlink.MAV_SEVERITY_INFO, "ahrsd: " + "y" * 120, 7)
        assert len(chunks) == 3
        assert not ep.send_together(chunks)
        assert queue.waiting_bytes() == 5 * 63 and counters.tx_dropped == 3
        assert counters.tx_dropped_by_priority == {1: 3}
        # the same through the one place texts are sent
        outbound = Outbound(Identity(1, 200, mavlink.MAV_TYPE_IMU), ServiceCounters(), clock=lambda: 0.0)
        outbound.endpoints.append(ep)
        outbound.statustext(mavlink.MAV_SEVERITY_INFO, "ahrsd: " + "y" * 120)
        assert queue.waiting_bytes() == 5 * 63 and counters.tx_dropped == 6
        # where the whole text fits (a priority-0 share, 576 B: 315 + 2 x 66), every chunk goes
        priority[0] = 0
        short = statustext_chunks(mavlink.MAV_SEVERITY_INFO, "ahrsd: " + "z" * 60, 8)
        assert len(short) == 2 and ep.send_together(short)
        assert queue.waiting_bytes() > 5 * 63 and counters.tx_messages == 5 + 2 and counters.tx_dropped == 6
    finally:
        queue.close()


def test_a_short_text_is_admitted_at_its_real_size_on_a_nearly_full_serial_link(full_pipe):
    """The same 5760 B/s link (432 B for priority 1) with 6 single texts waiting (6 x 63 = 378 B): 54 B are left.
    "ahrsd: ok" packs to 10 header + 10 payload (severity, 9 characters; the zero id and chunk_seq and the rest of
    the text are trailing zeros MAVLink 2 trims) + 2 CRC = 22 B, so it fits, through `send` and through
    `send_together` alike; taken at STATUSTEXT's largest frame (66 B) it would not."""
    w, loop = full_pipe
    counters = LinkCounters()
    queue = SerialOutQueue(w, 5760.0, loop, counters)
    conn = SimpleNamespace(mav=mavlink.MAVLink(queue, srcSystem=1, srcComponent=200), fd=None)
    ep = Endpoint("/dev/ttyAMA0,57600", 1, 200, lambda e, m: None, counters=counters, conn=conn,
                  priority_of=lambda message_id: 1, out_queue=queue)
    try:
        for k in range(6):
            (single,) = statustext_chunks(mavlink.MAV_SEVERITY_INFO, f"ahrsd: {k}" + "x" * 42, 0)
            assert ep.send(single)
        assert queue.waiting_bytes() == 378
        (short,) = statustext_chunks(mavlink.MAV_SEVERITY_INFO, "ahrsd: ok", 0)
        assert ep.send_together([short])
        assert queue.waiting_bytes() == 378 + 22 and counters.tx_dropped == 0
        (short,) = statustext_chunks(mavlink.MAV_SEVERITY_INFO, "ahrsd: ok", 0)
        assert ep.send(short)                                                   # 422 B: send agrees
        assert queue.waiting_bytes() == 378 + 2 * 22 and counters.tx_dropped == 0
    finally:
        queue.close()
