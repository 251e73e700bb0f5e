"""The polled reader's wakes for a source with a `ready_fd` (the reader process's pipe): a block is taken when the
descriptor becomes readable, not at the next tick; the tick stands in while nothing comes; after a failed poll
the reader waits out the retry and then takes blocks on arrival again.

Run on a real event loop with a pipe as the source's descriptor. The tick is made very slow (1 Hz) where a test
shows that a block did not wait for it: ten blocks handed over one after the other would take ten seconds on the
tick, and each test allows three (no figure of speed is asserted: the margin is a thousand-fold)."""

from __future__ import annotations

import asyncio
import os

from support.pipe_reader import _drive, _hand_over_and_wait, _rig


def test_each_block_is_taken_when_it_arrives_not_at_the_next_tick():
    source, reader, seen, published = _rig(poll_hz=1.0)

    async def body():
        for _ in range(10):                       # the next block only once the reader took this one
            await _hand_over_and_wait(source, seen, 3)

    _drive(reader, source, body)
    assert seen == list(range(30))
    assert source.polls_with_samples == [3] * 10          # one wake a block
    assert len(published) >= 10                           # the outputs go out after every block


def test_the_tick_stands_in_while_the_source_sends_nothing():
    source, reader, _, published = _rig(poll_hz=100.0)

    async def body():
        await asyncio.sleep(0.3)                  # 15 stand-in ticks at two periods each; a loaded machine fewer

    _drive(reader, source, body)
    assert len(published) >= 3                    # SYS_STATUS and the health checks go on without samples
    assert reader.health.last_empty_read_time > 0


def test_after_a_failed_poll_blocks_are_taken_on_arrival_again():
    source, reader, seen, published = _rig(poll_hz=1.0)

    async def body():
        await asyncio.sleep(0)
        source.fail_next = 1                      # this wake fails: retried after RETRY_AFTER_FAILURE_S (0.2 s)
        await _hand_over_and_wait(source, seen, 2)
        for _ in range(10):
            await _hand_over_and_wait(source, seen, 1)

    _drive(reader, source, body)
    assert seen == list(range(12))
    assert reader.counters.driver_errors == 1
    assert source.polls_with_samples == [2] + [1] * 10


def test_a_source_without_a_descriptor_is_polled_on_the_tick():
    source, reader, seen, _ = _rig(poll_hz=50.0)
    fd, source.ready_fd = source.ready_fd, None   # the same pipe, but the reader is not told of it

    async def body():
        source.ready_fd = fd                      # poll() reads it; the reader registered nothing
        await _hand_over_and_wait(source, seen, 2)

    _drive(reader, source, body)
    assert seen == [0, 1]


def test_after_the_last_block_the_tick_stands_in():
    source, reader, seen, published = _rig(poll_hz=100.0)

    async def body():
        await asyncio.sleep(0.05)                 # the reader's first look (a tick) done: the block comes as data
        await _hand_over_and_wait(source, seen, 2)
        taken = len(published)
        await asyncio.sleep(0.3)                  # 7 stand-in ticks at four periods, then two; a loaded machine fewer
        published.append(len(published) - taken)

    _drive(reader, source, body)
    assert published[-1] >= 3                     # outputs after the block went on without samples


def test_a_look_queued_before_the_reader_stopped_does_not_rearm_on_a_closed_source():
    """Ctrl-C of a daemon whose sensor keeps failing (walk27: `ahrsd run` on the shipped config with no
    /dev/spidev0.0): a look at the reader process's descriptor queued before the reader stopped ran after it, its
    failed poll armed the retry, and the retry re-registered the closed descriptor: "Exception in callback
    SampleReader._batch_retry() … OSError: [Errno 9] Bad file descriptor" after "stopping". A look after the stop
    now does nothing."""
    source, reader, _, _ = _rig(poll_hz=100.0)
    errors: list[dict] = []

    async def main():
        loop = asyncio.get_running_loop()
        loop.set_exception_handler(lambda _loop, context: errors.append(context))
        task = loop.create_task(reader.run(loop))
        await asyncio.sleep(0.05)
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        source.fail_next = 10                       # the sensor is still failing
        os.close(source.ready_fd)                   # the service closes the source at its stop
        reader._data_step()                         # the look that was already queued
        await asyncio.sleep(0.5)                    # past the retry (0.2 s)

    try:
        asyncio.run(asyncio.wait_for(main(), 3.0))
    finally:
        os.close(source._w)
    assert errors == [], errors
