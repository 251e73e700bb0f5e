"""Reads paced by the chip's own clock: the ADIS16405's data-ready output (DIO1, routed by MSC_CTRL: see
Adis16405.enable_data_ready) on a GPIO, read as edge events with libgpiod.

A host timer (drivers.sample_timer) must infer the chip's sample phase from its own reads and re-learn it as the
two oscillators drift apart (docs/drivers.md: what ±50 ppm does). An edge is the chip saying "sample ready"
itself: the reader wakes on it, reads once, and the kernel's edge events give the sample its time (the edge's
CLOCK_MONOTONIC time stamp, taken in the GPIO interrupt) and its index (the event's line sequence number counts
every edge, even those the kernel's event buffer dropped), so every sample the chip produced but nobody read is
counted exactly — no index ambiguity.

`DataReadyTimer` has the SampleTimer interface chip_source.ChipSource uses (fresh/stale/may_have_consumed/
next_read_time, k, ambiguous_*), plus `wait(timeout_s)`, which the reader thread (drivers.threaded_source) calls
instead of sleeping until next_read_time. The line is anything with libgpiod's LineRequest interface
(`wait_edge_events`, `read_edge_events`, `release`): the real GPIO (`open_gpio_line`) or the simulated chip's
DIO1 (drivers.simulated.SimulatedDataReadyLine).

libgpiod's Python bindings (`gpiod` on PyPI, v2 API) are an optional extra (`pip install '.[gpio]'` in the source tree),
imported only when a data-ready GPIO is configured: they need the Linux GPIO character device and build a C
extension, which development machines and the timer-paced set-up do not need.
"""

from __future__ import annotations

import logging
import shlex
import sys
from typing import Protocol

from ahrsd.drivers.errors import BusError

log = logging.getLogger(__name__)

GUARD_S = 50e-6          # next_read_time (event-loop reader only): this long after the predicted edge


class DataReadyLine(Protocol):
    """What the timer asks of the line: libgpiod's LineRequest for one line with rising-edge detection."""

    def wait_edge_events(self, timeout=None) -> bool: ...

    def read_edge_events(self, max_events: int | None = None) -> list: ...

    def release(self) -> None: ...


class DataReadyTimer:
    """Sample time stamps and indices from data-ready edges (see the module doc)."""

    ambiguous_reads = 0          # the edges' sequence numbers leave no ambiguity
    ambiguous_samples = 0
    waits_for_edges = True       # a reader thread calls wait(timeout_s) instead of sleeping until next_read_time

    def __init__(self, line: DataReadyLine, period_s: float):
        self.line = line
        self.period_s = period_s
        self.k = -1                  # index of the last fresh sample (edge sequence number − first + 0)
        self._seq: int | None = None
        self._pending: list = []     # edges taken by wait() for the next read
        self._need_new_edge = False
        self._last_edge_s: float | None = None
        self.stats = {"edges": 0, "edges_without_sample": 0, "reads_without_edge": 0}

    def wait(self, timeout_s: float) -> bool:
        """Block until the chip raises data-ready (True) or `timeout_s` passes (False)."""
        if self._pending and not self._need_new_edge:
            return True
        if not self.line.wait_edge_events(timeout_s):
            return False
        self._pending.extend(self.line.read_edge_events())
        self._need_new_edge = False
        return bool(self._pending)

    def _take(self) -> list:
        events, self._pending = self._pending, []
        if not events and self.line.wait_edge_events(0):
            events = self.line.read_edge_events()     # read without waiting (the event-loop reader)
        return events

    def fresh(self, read_time: float, read_end: float | None = None,
              newer_ready: bool = False) -> tuple[float, int, int]:
        """newer_ready: the read saw a newer sample ready by its end (register reads after the burst): its edge,
        if already taken from the line, is kept for the next read, which returns that sample."""
        events = self._take()
        self._need_new_edge = False
        if newer_ready and len(events) > 1:
            events, self._pending = events[:-1], events[-1:]
        if not events:
            # ND said new but no edge was seen: one sample after the last (the line missed it, or the
            # read raced the edge); timed by the read
            self.stats["reads_without_edge"] += 1
            self.k += 1
            return read_time, self.k, 0
        last = events[-1]
        seq = int(last.line_seqno)
        produced = 1 if self._seq is None else seq - self._seq
        self._seq = seq
        self.stats["edges"] += produced
        lost = produced - 1 if self.k >= 0 else 0
        self.k += produced
        self._last_edge_s = last.timestamp_ns * 1e-9
        return self._last_edge_s, self.k, lost

    def index_uncertain(self, read_time: float, read_end: float) -> bool:
        """Never: the edges' sequence numbers index the samples."""
        return False

    def fresh_if_certain(self, read_time: float, read_end: float) -> tuple[float, int, int]:
        """Always `fresh`: the index is never uncertain."""
        return self.fresh(read_time, read_end)

    def stale(self, read_time: float) -> None:
        """ND clear although an edge came: its sample was taken by an earlier register read (DIAG_STAT, the
        burst-bug check). The edges stay pending, so the next fresh read counts that sample as lost."""
        if self._pending:
            self.stats["edges_without_sample"] += 1
        self._need_new_edge = True

    def may_have_consumed(self, read_end: float) -> None:
        """Nothing to do: the edges count the samples whatever the reads consumed."""

    def next_read_time(self) -> float:
        """For a reader that cannot wait on the line (the event-loop reader): just after the predicted edge."""
        if self._last_edge_s is None:
            return 0.0
        return self._last_edge_s + self.period_s + GUARD_S

    def close(self) -> None:
        self.line.release()


def parse_gpio(spec: str) -> tuple[str, int]:
    """"gpiochip0:25" or "/dev/gpiochip0:25" -> ("/dev/gpiochip0", 25)."""
    chip, sep, offset = spec.rpartition(":")
    if not sep or not chip or not offset.isdigit():
        raise ValueError(f"data-ready GPIO {spec!r}: expected CHIP:LINE such as gpiochip0:25")
    return (chip if chip.startswith("/dev/") else f"/dev/{chip}"), int(offset)


def open_gpio_line(spec: str):
    """The data-ready GPIO as a libgpiod v2 line request: rising edges (DIO1 active high), time-stamped on
    CLOCK_MONOTONIC (the clock of every other sample time stamp)."""
    path, offset = parse_gpio(spec)
    try:
        import gpiod  # noqa: PLC0415  (optional dependency: ahrsd[gpio])
        from gpiod.line import Clock, Direction, Edge
    except ImportError as exc:
        # as drivers/spi.py: the interpreter's own pip and the package of pyproject's gpio extra
        raise BusError("data-ready pacing needs libgpiod's Python bindings (v2): "
                       f"{shlex.quote(sys.executable)} -m pip install 'gpiod>=2.1' — "
                       "or leave [sensor] data_ready empty to pace reads with the host timer") from exc
    try:
        return gpiod.request_lines(path, consumer="ahrsd-data-ready", config={offset: gpiod.LineSettings(
            direction=Direction.INPUT, edge_detection=Edge.RISING, event_clock=Clock.MONOTONIC)})
    except OSError as exc:
        raise BusError(f"cannot request {path} line {offset} for data-ready edges: {exc}") from exc

