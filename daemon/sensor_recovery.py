"""Keep the sensor alive: start-up failures and a vanished bus are retried with backoff, never a crash loop.

`ReconnectingSource` wraps the per-sample `DriverSource` (daemon.pipeline). Where the plain source raised
once at start (self-test failed, PRODUCT_ID wrong, /dev/spidev missing) and the daemon exited — under
systemd a restart loop — this one lets the daemon come up in CRITICAL (no heading published, STATUSTEXT with
the reason) and re-probes the chip with exponential backoff (0.2 s doubling to 5 s). A bus failure in
operation (device node gone, ioctl error) is handled the same way: the SPI node is re-opened and the chip
re-probed, re-self-tested and re-configured, because a chip that lost power comes back with its flash settings.
The SampleTimer is kept across the outage, so the samples missed while the device was away are counted as
lost (pipeline gaps, `SYS_STATUS.errors_count2`), not hidden.

While the sensor is down `read_one()` raises `SensorUnavailable` (a BusError); the service's reader counts
it, reports CRITICAL and calls again 0.2 s later — re-open attempts happen only when the backoff says so.

`report_sensor_alarms(service)` is a side task: every new kind of DIAG_STAT alarm (EA flag) is sent as one
STATUSTEXT (at most one per kind per ALARM_REPORT_PERIOD_S) so the ground station learns why samples are
flagged.
"""

from __future__ import annotations

import asyncio
import logging
import time

from ahrsd.drivers.errors import BusError, DriverError, SelfTestFailed
from ahrsd.drivers.registers import GLOB_CMD

log = logging.getLogger(__name__)

BACKOFF_FIRST_S = 0.2
BACKOFF_MAX_S = 5.0
ALARM_REPORT_PERIOD_S = 10.0
ALARM_CHECK_PERIOD_S = 0.5


# faults during which the sample flow stops or frames are rejected: samples lost there are explained
_FLOW_STOPPING = ("bus_error", "stall", "garbage", "short_read", "self_test_fail")


def _sample_timer_class():
    from ahrsd.daemon.pipeline import SampleTimer
    return SampleTimer


class StallAwareSampleTimer(_sample_timer_class()):
    """pipeline.SampleTimer that tells a data-ready stall from a phase error.

    The base class learns the chip's sample phase from stale reads; when a stale read comes more than
    STALL_PERIODS after the sample was due, it drags its phase estimate forward, so after a stall of S
    samples the sample index does not advance: the S samples the chip never produced are not counted as lost.
    Here, a read that late is a stall: the phase is kept, and the first sample after the stall gets the
    index its time says (the gap is counted, the estimator sees the real Δt).
    """

    STALL_PERIODS = 2.0

    stalled_reads = 0
    _hi_fresh: float | None = None      # the phase upper bound after the last fresh read (never dragged)

    def fresh(self, read_time: float, read_end: float | None = None) -> tuple[float, int, int]:
        out = super().fresh(read_time, read_end)
        self._hi_fresh, self._lo_fresh = self.hi, self.lo
        return out

    def stale(self, read_time: float) -> None:
        if (self._hi_fresh is not None
                and read_time - (self.k + 1) * self.period_s >= self._hi_fresh + self.STALL_PERIODS * self.period_s):
            # undo what the first stale reads of the stall did: they were taken as "sample k+1 not ready",
            # but the stalled chip had produced it (ND held clear); that raised lo past the true phase (so the
            # sample after the stall came out one index low) even when it did not drag hi
            self.hi, self.lo = self._hi_fresh, self._lo_fresh
            self.stalled_reads += 1
            return
        super().stale(read_time)


class _BurstIndexTap:
    """The simulated chip as the SPI bus, noting the chip's sample index at each burst: the ground truth of
    the sample a burst returned (`chip.sample_index` after the read can be one further when the driver went
    on with a register read — burst-bug check, DIAG_STAT — during which the chip produced the next sample)."""

    def __init__(self, chip):
        self.chip = chip
        self.burst_index = -1

    def transfer(self, tx: bytes, speed_hz: int, delay_us: int = 0) -> bytes:
        rx = self.chip.transfer(tx, speed_hz, delay_us)
        if tx[0] == GLOB_CMD and tx[1] == 0:          # 0x3E00 starts a burst read
            self.burst_index = self.chip.sample_index
        return rx

    def __getattr__(self, name):
        return getattr(self.chip, name)


class SensorUnavailable(BusError):
    """The sensor is down and waiting for its next re-open attempt."""


class ReconnectingSource:
    """A DriverSource that (re)opens the bus and (re)starts the ADIS16405 driver with backoff.

    open_bus: () -> SpiBus, called for every (re)open (a real spidev node is re-opened; the simulated chip
        returns the same chip, which keeps running like a device that stays powered).
    """

    per_sample = True
    monotonic_offset_s = 0.0

    def __init__(self, open_bus, description: str, *, clock=time.monotonic, reopen_same_bus: bool = False):
        from ahrsd.daemon.pipeline import ADIS16405_RATE_HZ

        self._open_bus = open_bus
        self._clock = clock
        self._reopen_same_bus = reopen_same_bus
        self.description = description
        self.sample_rate_hz = ADIS16405_RATE_HZ
        self._inner: DriverSource | None = None   # created at the first successful start; its SampleTimer
        self.bus = None
        self.driver = None
        self.up = False
        self.last_error = ""
        self.backoff_s = BACKOFF_FIRST_S
        self.next_attempt = 0.0
        self.stats = {"open_attempts": 0, "open_failures": 0, "reopens": 0, "bus_failures": 0,
                      "self_test_failures_at_start": 0, "lost_in_fault_windows": 0, "lost_after_reconnect": 0,
                      "lost_outside_faults": 0, "index_mismatches": 0}
        self._last_counter = -1
        self.chip = None              # the simulated chip, when there is one (ground truth for the soak)
        self.first_chip_index: int | None = None
        self.last_chip_index: int | None = None
        self._reads_started = False
        self._just_reopened = False
        self._unreported = True

    def _rebase_faults(self, kinds_excluded=()) -> None:
        """Fault windows count chip samples from now (the chip ran while the daemon was loading)."""
        plan = getattr(self.chip, "faults", None)
        if plan is None:
            return
        base = max(0, self.chip.sample_index + 1, int(self.chip.now() * self.chip.sample_rate_hz) + 1)
        for f in plan.faults:
            if f.kind.value in kinds_excluded:
                continue
            f.start_sample += base
            if f.stop_sample is not None:
                f.stop_sample += base

    def start(self) -> None:
        """First start attempt (a failure leaves the source down, retried from read_one)."""
        if self.chip is not None:
            self._rebase_faults()
        self._try_open(self._clock())

    # -- opening ------------------------------------------------------------------------------------------------

    def _try_open(self, now: float) -> bool:
        from ahrsd.daemon.pipeline import DriverSource
        from ahrsd.drivers.adis16405 import Adis16405

        self.stats["open_attempts"] += 1
        try:
            if self.bus is None or not self._reopen_same_bus:
                self._close_bus()
                self.bus = self._open_bus()
            if self.driver is None:
                self.driver = Adis16405(self.bus)
            else:
                self.driver.bus = self.bus
            self.driver.start()
        except DriverError as exc:
            self._failed(now, exc, opening=True)
            return False
        except OSError as exc:       # a bus that raises plain OSErrors outside the driver's wrapper
            self._failed(now, BusError(str(exc)), opening=True)
            return False
        if self._inner is None:
            self._inner = DriverSource(self.driver, self.bus, self.description, clock=self._clock)
            self._inner.timer = StallAwareSampleTimer(self._inner.timer.period_s)
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

    # -- the SampleSource interface ------------------------------------------------------------------------------

    def read_one(self, now: float):
        if not self._reads_started:
            self._reads_started = True
            if self.chip is not None:      # run-time faults count from the reader's first read
                self._rebase_faults(kinds_excluded=("self_test_fail",))
        if not self.up:
            if self._unreported and self._inner is None:
                self._unreported = False     # the service hears of a failed start even if the retry would work
                raise SensorUnavailable(self.last_error)
            if now < self.next_attempt or not self._try_open(now):
                raise SensorUnavailable(self.last_error)
            self._just_reopened = True
            now = self._clock()          # the start (probe, self-test) took chip time: index by the read time
        try:
            s = self._inner.read_one(now)
        except BusError as exc:
            self.stats["bus_failures"] += 1
            self._failed(now, exc, opening=False)
            raise
        if s is not None and self.chip is not None:
            self._account(s)
        return s

    def _account(self, s) -> None:
        """Ground truth bookkeeping on the simulated chip: chip index range read, lost samples by cause."""
        tap = self.bus if isinstance(self.bus, _BurstIndexTap) else None
        idx = tap.burst_index if tap is not None else self.chip.sample_index
        prev = self.last_chip_index
        if self.first_chip_index is None:
            self.first_chip_index = idx
        self.last_chip_index = idx
        reopened, self._just_reopened = self._just_reopened, False
        prev_counter, self._last_counter = self._last_counter, s.counter
        if prev is not None and idx - prev != s.counter - prev_counter:
            self.stats["index_mismatches"] += 1
            log.debug("sample index mismatch: chip +%d, daemon +%d (flags %s, reopened %s)", idx - prev,
                      s.counter - prev_counter, s.flags, reopened)
        if prev is None or idx - prev <= 1:
            return
        lost = idx - prev - 1
        lo, hi = prev + 1, idx                      # lost chip samples: [lo, hi)
        if any(f.kind.value in _FLOW_STOPPING and f.start_sample < hi
               and (f.stop_sample is None or f.stop_sample > lo) for f in self.chip.faults.faults):
            self.stats["lost_in_fault_windows"] += lost
        elif reopened:
            self.stats["lost_after_reconnect"] += lost
        else:
            self.stats["lost_outside_faults"] += lost

    def next_read_time(self) -> float:
        return self._inner.next_read_time() if self._inner is not None else 0.0

    def poll(self, now: float | None = None):
        s = self.read_one(self._clock() if now is None else now)
        return [] if s is None else [s]

    def counters(self) -> dict:
        c = self._inner.counters() if self._inner is not None else {}
        c.update({f"sensor_{k}": v for k, v in self.stats.items()})
        if self.first_chip_index is not None:
            c["chip_first_index_read"] = self.first_chip_index
            c["chip_last_index_read"] = self.last_chip_index
        return c

    def close(self) -> None:
        self._reopen_same_bus = False
        self._close_bus()


def open_sensor_source(sensor_cfg, clock=time.monotonic, faults=None) -> ReconnectingSource:
    """The chip source of `ahrsd run` (`sim` or `spi`) with start-up retries and bus reconnection.

    faults: a drivers.faults.FaultPlan for the simulated chip (refused for a real sensor).
    """
    if sensor_cfg.source == "spi":
        if faults is not None:
            raise ValueError("fault injection (--sim-faults) needs the simulated sensor, not --spi")
        from ahrsd.drivers.spi import SpidevBus

        path = sensor_cfg.spi_device
        src = ReconnectingSource(lambda: SpidevBus(path), f"ADIS16405 on {path}", clock=clock)
        src.start()
        return src
    if sensor_cfg.source != "sim":
        raise ValueError(f"no chip source for sensor.source = {sensor_cfg.source!r}")
    from ahrsd.drivers.simulated import SimulatedAdis16405

    chip = SimulatedAdis16405(scenario=sensor_cfg.scenario, seed=sensor_cfg.seed, errors=sensor_cfg.errors,
                              clock=clock, faults=faults)
    what = f"simulated ADIS16405 ({sensor_cfg.scenario}{', faults injected' if faults is not None else ''})"
    tap = _BurstIndexTap(chip)
    src = ReconnectingSource(lambda: tap, what, clock=clock, reopen_same_bus=True)
    src.chip = chip
    src.start()
    return src


async def report_sensor_alarms(service, period_s: float = ALARM_CHECK_PERIOD_S) -> None:
    """STATUSTEXT for new DIAG_STAT alarm kinds and start-up/bus failures counted by the driver."""
    from ahrsd.daemon.mavlink_io import mavlink

    seen: dict[str, int] = {}
    last_sent: dict[str, float] = {}
    while True:
        await asyncio.sleep(period_s)
        source = service.source
        counters = source.counters() if source is not None and hasattr(source, "counters") else {}
        now = time.monotonic()
        for key, value in counters.items():
            if not key.startswith("diag_") or value <= seen.get(key, 0):
                continue
            seen[key] = value
            if now - last_sent.get(key, -1e9) >= ALARM_REPORT_PERIOD_S:
                last_sent[key] = now
                service.statustext(mavlink.MAV_SEVERITY_WARNING, f"ahrsd: sensor alarm {key[5:].upper()}"[:50])
