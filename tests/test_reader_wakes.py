"""The polled reader's wakes for a source with a `ready_fd` (the reader process's pipe): a block is taken when the
descriptor becomes readable, not at the next tick; the tick stands in while nothing comes; after a failed poll
the reader waits out the retry and then takes blocks on arrival again.

Run on a real event loop with a pipe as the source's descriptor. The tick is made very slow (1 Hz) where a test
shows that a block did not wait for it: ten blocks handed over one after the other would take ten seconds on the
tick, and each test allows three (no figure of speed is asserted: the margin is a thousand-fold)."""

from __future__ import annotations

import asyncio
import os

from ahrsd.calibration.models import Calibration
from ahrsd.core.sample import make_sample
from ahrsd.daemon.counters import ServiceCounters
from ahrsd.daemon.health import Health
from ahrsd.daemon.pipeline import Pipeline
from ahrsd.daemon.sample_reader import ReaderOutputs, SampleListeners, SampleReader
from ahrsd.drivers.errors import BusError
from ahrsd.drivers.source_interface import LiveSource

from support.stub_estimator import StubEstimator


class PipeSource(LiveSource):
    """A block source whose descriptor is a pipe: each byte written is one sample; `fail_next` polls raise."""

    sample_rate_hz = 100.0
    per_sample = False

    def __init__(self):
        self.ready_fd, self._w = os.pipe()
        os.set_blocking(self.ready_fd, False)
        self.counter = 0
        self.fail_next = 0
        self.polls_with_samples: list[int] = []

    def hand_over(self, n: int) -> None:
        os.write(self._w, b"x" * n)

    def poll(self):
        if self.fail_next:
            self.fail_next -= 1
            raise BusError("the reader process reported a bus failure")
        try:
            n = len(os.read(self.ready_fd, 4096))
        except BlockingIOError:
            n = 0
        out = []
        for _ in range(n):
            out.append(make_sample(self.counter * 0.01, [0, 0, 0], [0, 0, -9.8], [20, 0, 40], counter=self.counter))
            self.counter += 1
        if out:
            self.polls_with_samples.append(len(out))
        return out

    def counters(self):
        return {}

    def close(self):
        os.close(self.ready_fd)
        os.close(self._w)


def _reader(source, poll_hz, published):
    return SampleReader(source, Pipeline(StubEstimator(), Calibration.identity()), Health(stale_timeout_s=0.1),
                        ServiceCounters(), SampleListeners(),
                        ReaderOutputs(publish=lambda now: published.append(now), statustext=lambda sev, text: None,
                                      heading_reset=lambda: None, ready=lambda: None),
                        poll_hz=poll_hz)


def _rig(poll_hz: float):
    """(source, reader, counters its listener saw, publish times)."""
    source = PipeSource()
    published: list[float] = []
    reader = _reader(source, poll_hz=poll_hz, published=published)
    seen: list[int] = []
    reader.listeners.add(lambda s, e: seen.append(s.counter))
    return source, reader, seen, published


def _drive(reader, source, body) -> None:
    """Run `reader` on a fresh event loop while `body()` (a coroutine function) hands blocks over; at most 3 s."""
    async def main():
        loop = asyncio.get_running_loop()
        task = loop.create_task(reader.run(loop))
        await body()
        task.cancel()

    try:
        asyncio.run(asyncio.wait_for(main(), 3.0))
    finally:
        source.close()


async def _hand_over_and_wait(source, seen, n: int) -> None:
    """n samples handed over; back once the reader's listener has seen them."""
    want = len(seen) + n
    source.hand_over(n)
    while len(seen) < want:
        await asyncio.sleep(0)


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
