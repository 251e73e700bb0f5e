"""Keep the sensor alive: start-up failures and a vanished bus are retried with backoff, never a crash loop.

`ReconnectingSource` wraps the per-sample `ChipSource`. Where a plain source raises once at start (self-test
failed, PRODUCT_ID wrong, /dev/spidev missing) and the daemon would exit — under systemd a restart loop — this
one lets the daemon come up in CRITICAL (no heading published, STATUSTEXT with the reason) and re-probes the
chip with exponential backoff (0.2 s doubling to 5 s). A bus failure in operation (device node gone, ioctl
error) is handled the same way: the SPI node is re-opened and the chip re-probed, re-self-tested and
re-configured, because a chip that lost power comes back with its flash settings. The SampleTimer is kept
across the outage, so the samples missed while the device was away are counted as lost (GAP_BEFORE), not hidden.

While the sensor is down `read_one()` raises `SensorUnavailable` (a BusError); the reader counts it, reports
CRITICAL and calls again 0.2 s later — re-open attempts happen only when the backoff says so.
"""

from __future__ import annotations

import logging
import time

from ahrsd.drivers.chip_source import ADIS16405_RATE_HZ, ChipSource
from ahrsd.drivers.errors import BusError, DriverError, SelfTestFailed
from ahrsd.drivers.registers import nearest_rate_hz
from ahrsd.drivers.sample_timer import StallAwareSampleTimer
from ahrsd.drivers.source_interface import LiveSource

log = logging.getLogger(__name__)

BACKOFF_FIRST_S = 0.2
BACKOFF_MAX_S = 5.0


class SensorUnavailable(BusError):
    """The sensor is down and waiting for its next re-open attempt."""


class ReconnectingSource(LiveSource):
    """A ChipSource that (re)opens the bus and (re)starts the driver with backoff.

    open_bus: () -> SpiBus, called for every (re)open (a real spidev node is re-opened; the simulated chip
        returns the same chip, which keeps running like a device that stays powered).
    make_driver: (bus) -> driver with start() and read_sample(stamp) (drivers.source.open_chip_driver).
    sample_rate_hz: the chip's output data rate, written (SMPL_PRD, `start(sample_rate_hz=...)`) at every
        (re)start: a chip that lost power comes back at its flash setting. None: the chip's own setting.
    """

    description: str
    sample_rate_hz: float
    per_sample = True
    monotonic_offset_s = 0.0

    def __init__(self, open_bus, make_driver, description: str, *, clock=time.monotonic,
                 reopen_same_bus: bool = False, make_timer=StallAwareSampleTimer,
                 sample_rate_hz: float | None = None):
        self._open_bus = open_bus
        self._make_driver = make_driver
        self._clock = clock
        self._reopen_same_bus = reopen_same_bus
        self._make_timer = make_timer      # (period_s) -> the sample timer (drivers.data_ready: edges)
        self.description = description
        self._start_options = {} if sample_rate_hz is None else {"sample_rate_hz": sample_rate_hz}
        # until the first start reads it back: the rate asked for (the reader paces a chip that is down by it)
        self.sample_rate_hz = ADIS16405_RATE_HZ if sample_rate_hz is None else nearest_rate_hz(sample_rate_hz)
        self._inner: ChipSource | None = None   # created at the first successful start; keeps its SampleTimer
        self.bus = None
        self.driver = None
        self.up = False
        self.last_error = ""
        self.backoff_s = BACKOFF_FIRST_S
        self.next_attempt = 0.0
        self.stats = {"open_attempts": 0, "open_failures": 0, "reopens": 0, "bus_failures": 0,
                      "self_test_failures_at_start": 0}
        self._unreported = True

    def start(self) -> None:
        """First start attempt (a failure leaves the source down, retried from read_one)."""
        self._try_open(self._clock())

    # -- opening ------------------------------------------------------------------------------------------------

    def _try_open(self, now: float) -> bool:
        self.stats["open_attempts"] += 1
        try:
            if self.bus is None or not self._reopen_same_bus:
                self._close_bus()
                self.bus = self._open_bus()
            if self.driver is None:
                self.driver = self._make_driver(self.bus)
            else:
                self.driver.bus = self.bus
            self.driver.start(**self._start_options)
        except DriverError as exc:
            self._failed(now, exc, opening=True)
            return False
        except OSError as exc:       # a bus that raises plain OSErrors outside the driver's wrapper
            self._failed(now, BusError(str(exc)), opening=True)
            return False
        if self._inner is None:
            self._inner = ChipSource(self.driver, self.bus, self.description, clock=self._clock,
                                     timer=self._make_timer(1.0 / self.driver.sample_rate_hz))
            self.sample_rate_hz = self._inner.sample_rate_hz
        else:
            self._inner.driver, self._inner.bus = self.driver, self.bus
            self.stats["reopens"] += 1
        if self.last_error:
            log.info("sensor back after %s", self.last_error)
        self.up, self.last_error, self.backoff_s = True, "", BACKOFF_FIRST_S
        return True

    def _failed(self, now: float, exc: Exception, opening: bool) -> None:
        if opening:
            self.stats["open_failures"] += 1
            if isinstance(exc, SelfTestFailed) and self._inner is None:
                self.stats["self_test_failures_at_start"] += 1
        reason = str(exc) or type(exc).__name__
        if reason != self.last_error:
            log.error("sensor %s: %s; retrying in %.1f s", "start failed" if opening else "lost", reason,
                      self.backoff_s)
        self.up, self.last_error = False, reason
        self.next_attempt = now + self.backoff_s
        self.backoff_s = min(BACKOFF_MAX_S, 2.0 * self.backoff_s)

    def _close_bus(self) -> None:
        if self.bus is not None and not self._reopen_same_bus:
            try:
                self.bus.close()
            except Exception:  # noqa: BLE001 - a dead bus may fail to close
                log.debug("closing the bus failed", exc_info=True)
            self.bus = None

    # -- the SensorSource interface ------------------------------------------------------------------------------

    @property
    def timer(self):
        return None if self._inner is None else self._inner.timer

    def read_one(self, now: float):
        if not self.up:
            if self._unreported and self._inner is None:
                self._unreported = False     # the reader hears of a failed start even if the retry would work
                raise SensorUnavailable(self.last_error)
            if now < self.next_attempt or not self._try_open(now):
                raise SensorUnavailable(self.last_error)
            now = self._clock()          # the start (probe, self-test) took chip time: index by the read time
        try:
            return self._inner.read_one(now)
        except BusError as exc:
            self.stats["bus_failures"] += 1
            self._failed(now, exc, opening=False)
            raise

    def next_read_time(self) -> float:
        return self._inner.next_read_time() if self._inner is not None else 0.0

    def poll(self, now: float | None = None):
        s = self.read_one(self._clock() if now is None else now)
        return [] if s is None else [s]

    def counters(self) -> dict:
        c = self._inner.counters() if self._inner is not None else {}
        c.update({f"sensor_{k}": v for k, v in self.stats.items()})
        return c

    def close(self) -> None:
        self._reopen_same_bus = False
        self._close_bus()
