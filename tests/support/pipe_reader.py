"""A block source on a pipe and the polled SampleReader over it, on a real event loop: each byte written is one
sample (tests/test_reader_wakes.py, tests/test_gnss_after_output.py)."""

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
