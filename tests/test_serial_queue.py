"""The serial output queue's admission (daemon.serial_queue) with worked numbers, on a pipe nobody reads: the
bytes it accepts wait in it, so its fill is exactly what it was given.

A line of 20 000 B/s and QUEUE_SECONDS = 0.1 s give a bound of 2000 bytes; priority p is admitted while the fill
after the frame stays within ADMIT_FRACTION[p] of it: 2000 B for 0 (VPE, HEARTBEAT), 1500 for 1, 1000 for 2,
500 for 3 and beyond. An empty queue takes any frame (a frame larger than its share is never starved)."""

from __future__ import annotations

import asyncio
import os

import pytest

from ahrsd.daemon.mavlink_io import LinkCounters
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
