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
from ahrsd.core.estimate import EstimateFlags
from ahrsd.core.sample import make_sample
from ahrsd.daemon.counters import ServiceCounters
from ahrsd.daemon.health import Health
from ahrsd.daemon.pipeline import Pipeline
from ahrsd.daemon.sample_reader import ReaderOutputs, SampleListeners, SampleReader
from ahrsd.drivers.errors import BusError
from ahrsd.drivers.source_interface import LiveSource


class _Est:
    flags = EstimateFlags.NONE


class _StubEstimator:
    def update(self, sample):
        return _Est()


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
    return SampleReader(source, Pipeline(_StubEstimator(), Calibration.identity()), Health(stale_timeout_s=0.1),
                        ServiceCounters(), SampleListeners(),
                        ReaderOutputs(publish=lambda now: published.append(now), statustext=lambda sev, text: None,
                                      heading_reset=lambda: None, ready=lambda: None),
                        poll_hz=poll_hz)


def _run(coro):
    return asyncio.run(asyncio.wait_for(coro, 3.0))


def test_each_block_is_taken_when_it_arrives_not_at_the_next_tick():
    source = PipeSource()
    published: list[float] = []
    reader = _reader(source, poll_hz=1.0, published=published)
    seen: list[int] = []
    reader.listeners.add(lambda s, e: seen.append(s.counter))

    async def main():
        loop = asyncio.get_running_loop()
        task = loop.create_task(reader.run(loop))
        for k in range(10):                       # the next block only once the reader took this one
            source.hand_over(3)
            while len(seen) < 3 * (k + 1):
                await asyncio.sleep(0)
        task.cancel()

    try:
        _run(main())
    finally:
        source.close()
    assert seen == list(range(30))
    assert source.polls_with_samples == [3] * 10          # one wake a block
    assert len(published) >= 10                           # the outputs go out after every block


def test_the_tick_stands_in_while_the_source_sends_nothing():
    source = PipeSource()
    published: list[float] = []
    reader = _reader(source, poll_hz=100.0, published=published)

    async def main():
        loop = asyncio.get_running_loop()
        task = loop.create_task(reader.run(loop))
        await asyncio.sleep(0.3)                  # 15 stand-in ticks at two periods each; a loaded machine fewer
        task.cancel()

    try:
        _run(main())
    finally:
        source.close()
    assert len(published) >= 3                    # SYS_STATUS and the health checks go on without samples
    assert reader.health.last_empty_read_time > 0


def test_after_a_failed_poll_blocks_are_taken_on_arrival_again():
    source = PipeSource()
    published: list[float] = []
    reader = _reader(source, poll_hz=1.0, published=published)
    seen: list[int] = []
    reader.listeners.add(lambda s, e: seen.append(s.counter))

    async def main():
        loop = asyncio.get_running_loop()
        task = loop.create_task(reader.run(loop))
        await asyncio.sleep(0)
        source.fail_next = 1
        source.hand_over(2)                       # this wake fails: retried after RETRY_AFTER_FAILURE_S (0.2 s)
        while len(seen) < 2:
            await asyncio.sleep(0)
        for k in range(10):
            source.hand_over(1)
            while len(seen) < 3 + k:
                await asyncio.sleep(0)
        task.cancel()

    try:
        _run(main())
    finally:
        source.close()
    assert seen == list(range(12))
    assert reader.counters.driver_errors == 1
    assert source.polls_with_samples == [2] + [1] * 10


def test_a_source_without_a_descriptor_is_polled_on_the_tick():
    source = PipeSource()
    fd = source.ready_fd
    source.ready_fd = None                        # the same pipe, but the reader is not told of it
    published: list[float] = []
    reader = _reader(source, poll_hz=50.0, published=published)
    seen: list[int] = []
    reader.listeners.add(lambda s, e: seen.append(s.counter))

    async def main():
        loop = asyncio.get_running_loop()
        task = loop.create_task(reader.run(loop))
        os.write(source._w, b"xx")
        source.ready_fd = fd                      # poll() reads it; the reader registered nothing
        while len(seen) < 2:
            await asyncio.sleep(0.001)
        task.cancel()

    try:
        _run(main())
    finally:
        source.close()
    assert seen == [0, 1]
