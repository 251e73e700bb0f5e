"""Housekeeping at 10 Hz: a list of jobs, each `job(now)` deciding itself whether it is due. The daemon's jobs
(daemon.service, in this order): the health report (heartbeat, CPU load, MAV_STATE changes, systemd watchdog),
the status line, the signing timestamp, the GNSS task, the declination refresh, the heading slew check.
Adding a periodic job is one more entry in that list."""

from __future__ import annotations

import asyncio
import time
from typing import Callable, Protocol

from ahrsd.daemon import messages as msgs
from ahrsd.daemon.health import STATE_NAMES, Health
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.notify import Notifier
from ahrsd.daemon.outbound import Outbound

HOUSEKEEPING_HZ = 10.0
HEARTBEAT_PERIOD_S = 1.0


class Housekeeping:
    """Runs every job at HOUSEKEEPING_HZ on absolute deadlines of the event loop's clock.

    Each tick is a loop callback at its deadline (`loop.call_at`), not a task resumed by `asyncio.sleep`: the
    sleep's timer sets a future, whose callback resumes the task one loop iteration later, so a tick would
    cost two wakes of the loop instead of one. A job that raises ends `run` with its exception."""

    def __init__(self, jobs: list[Callable[[float], None]]):
        self.jobs = jobs

    async def run(self, loop: asyncio.AbstractEventLoop) -> None:
        period_s = 1.0 / HOUSEKEEPING_HZ
        done = loop.create_future()
        deadline = loop.time()
        handle: asyncio.Handle | None = None

        def tick() -> None:
            nonlocal deadline, handle
            deadline += period_s
            try:
                now = loop.time()
                for job in self.jobs:
                    job(now)
            except Exception as exc:  # noqa: BLE001 - ends run() as the task's exception
                if not done.done():
                    done.set_exception(exc)
                return
            # a late tick runs the next one at once (asyncio.sleep(0)'s next iteration), never skipping one
            handle = loop.call_at(max(loop.time(), deadline), tick)

        handle = loop.call_soon(tick)
        try:
            await done
        finally:
            handle.cancel()


class SampleCount(Protocol):
    samples: int


class Every:
    """`Every(period_s, fn, first_at)(now)` calls fn(now) when due: a housekeeping job at a slower rate."""

    def __init__(self, period_s: float, fn: Callable[[float], None], first_at: float):
        self.period_s = period_s
        self.fn = fn
        self.next_at = first_at

    def __call__(self, now: float) -> None:
        if now >= self.next_at:
            self.next_at = now + self.period_s
            self.fn(now)


class HealthReport:
    """The heartbeat (1 Hz), CPU load and measured sample rate, a STATUSTEXT + systemd status on every
    MAV_STATE change, and the systemd watchdog (only while samples flow: a stalled reader gets us restarted).
    Owns `load_permille` and `measured_rate_hz`."""

    def __init__(self, health: Health, outbound: Outbound, notifier: Notifier, counts: SampleCount, *,
                 watchdog_interval_s: float | None, start: float,
                 cpu_clock: Callable[[], float] = time.process_time,
                 standby_detail: Callable[[], str] = lambda: "initialising, no heading out",
                 active_detail: Callable[[], str] = lambda: "heading good",
                 last_sample_t_s: Callable[[], float | None] = lambda: None):
        self.health = health
        self.outbound = outbound
        self.notifier = notifier
        self.counts = counts
        self.last_sample_t_s = last_sample_t_s     # the last sample's time stamp (the pipeline's), or None
        self.watchdog_interval_s = watchdog_interval_s
        self.cpu_clock = cpu_clock
        self.standby_detail = standby_detail       # why no heading is good (daemon.heading_status)
        self.active_detail = active_detail         # "heading good", or what it rests on (daemon.heading_status)
        self.load_permille = 0
        self.measured_rate_hz: float | None = None     # None until one rate window has passed
        self._next_heartbeat = start + HEARTBEAT_PERIOD_S
        self._next_watchdog = start
        self._last_state: int | None = None
        self._cpu_window: tuple[float, float] = (start, cpu_clock())     # on the clock of `now`
        self._rate_window: tuple[float, int, float | None] = (0.0, 0, None)   # (clock, samples, last time stamp)

    def __call__(self, now: float) -> None:
        self.health.housekeeping_tick()
        if now >= self._next_heartbeat:
            self._next_heartbeat = max(self._next_heartbeat + HEARTBEAT_PERIOD_S, now)
            self._update_load(now)
            self.send_heartbeat(now)
        state = self.health.system_status(now)
        if state != self._last_state:
            self._on_state_change(state)
            self._last_state = state
        if (self.watchdog_interval_s is not None and now >= self._next_watchdog
                and self.health.samples_flowing(now)):
            self.notifier.watchdog()
            self._next_watchdog = now + self.watchdog_interval_s

    def send_heartbeat(self, now: float) -> None:
        self.outbound.send(msgs.heartbeat(self.outbound.identity.mav_type, self.health.system_status(now)))

    def _update_load(self, now: float) -> None:
        t0, cpu0 = self._cpu_window
        cpu = self.cpu_clock()
        if now > t0:
            self.load_permille = int(1000.0 * (cpu - cpu0) / (now - t0))
        self._cpu_window = (now, cpu)
        # The rate on the sensor's clock: the samples delivered over the span of their own time stamps. Blocks
        # arrive in bursts when the machine is busy (the reader's hand-overs, the kernel buffer's reads), so a
        # count over a second of the event loop's clock reads a catching-up burst as a faster chip; a lost sample
        # still lowers the rate (it is not delivered, its time passes).
        t_prev, n_prev, ts_prev = self._rate_window
        n, ts = self.counts.samples, self.last_sample_t_s()
        if t_prev:
            if ts is not None and ts_prev is not None and ts > ts_prev:
                self.measured_rate_hz = (n - n_prev) / (ts - ts_prev)
            else:
                self.measured_rate_hz = (n - n_prev) / (now - t_prev)     # no sample since, or none yet
        self._rate_window = (now, n, ts)

    def _on_state_change(self, new: int) -> None:
        name = STATE_NAMES.get(new, str(new))
        severity = {mavlink.MAV_STATE_CRITICAL: mavlink.MAV_SEVERITY_CRITICAL,
                    mavlink.MAV_STATE_ACTIVE: mavlink.MAV_SEVERITY_NOTICE}.get(new, mavlink.MAV_SEVERITY_INFO)
        detail = {
            mavlink.MAV_STATE_BOOT: "waiting for the sensor",
            mavlink.MAV_STATE_STANDBY: self.standby_detail(),
            mavlink.MAV_STATE_ACTIVE: self.active_detail(),   # Health: only while daemon.heading_status says so
            mavlink.MAV_STATE_CALIBRATING: self.health.calibrating or "calibrating",
            mavlink.MAV_STATE_CRITICAL: self.health.sensor_error or "no samples from the sensor",
        }.get(new, "")
        # a detail longer than one STATUSTEXT ("ahrsd: STANDBY: heading unknown (mag not calibrated), no heading
        # out") goes out whole, in chunks (daemon.outbound)
        self.outbound.statustext(severity, f"ahrsd: {name}: {detail}")
        self.notifier.status(f"{name}: {detail}")
