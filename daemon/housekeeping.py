"""Housekeeping at 10 Hz: heartbeat and CPU load, MAV_STATE changes (STATUSTEXT + systemd status), the
systemd watchdog (only while samples flow), the status line, the signing timestamp, declination refresh."""

from __future__ import annotations

import asyncio
import time

from ahrsd.daemon.health import STATE_NAMES
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.notify import watchdog_interval_s
from ahrsd.daemon.signing import save_timestamp
from ahrsd.daemon.status_line import format_status

HOUSEKEEPING_HZ = 10.0
STATUS_LINE_PERIOD_S = 0.5
SIGNING_SAVE_PERIOD_S = 30.0
DECLINATION_UPDATE_PERIOD_S = 10.0
VISION_POSITION_ESTIMATE = mavlink.MAVLINK_MSG_ID_VISION_POSITION_ESTIMATE


class Housekeeping:
    """Service part: the housekeeping task (`_housekeeping`)."""

    async def _housekeeping(self) -> None:
        loop = self.loop
        period = 1.0 / HOUSEKEEPING_HZ
        wd_interval = watchdog_interval_s(self.environ)
        start = loop.time()
        next_hb = start + 1.0
        next_wd = start
        next_line = start
        next_sign = start + SIGNING_SAVE_PERIOD_S
        deadline = start
        while True:
            deadline += period
            now = loop.time()
            if now >= next_hb:
                next_hb = max(next_hb + 1.0, now)
                self._update_load(now)
                self._send_heartbeat(now)
            self._update_heading_status(now)
            state = self.health.system_status(now)
            if state != self._last_state:
                self._on_state_change(self._last_state, state)
                self._last_state = state
            if wd_interval is not None and now >= next_wd and self.health.samples_flowing(now):
                self.notifier.watchdog()     # only while samples flow: a stalled reader gets us restarted
                next_wd = now + wd_interval
            if self._status_line is not None and now >= next_line:
                next_line = now + STATUS_LINE_PERIOD_S
                self._status_line.update(format_status(self, now))
            if self.signing_key is not None and now >= next_sign:
                next_sign = now + SIGNING_SAVE_PERIOD_S
                save_timestamp(self.state_dir, max(e.signing_timestamp() for e in self.endpoints))
            if self.gnss is not None:
                self.gnss.tick(now)
            if now - self._last_decl_update > DECLINATION_UPDATE_PERIOD_S:
                self._resolve_declination()
            if self.heading_slew.active and not any(ep.schedule.rate_hz(VISION_POSITION_ESTIMATE) > 0
                                                    for ep in self.endpoints):
                self.heading_slew.active = False    # nobody receives the slewed yaw: nothing to bring in
            await asyncio.sleep(max(0.0, deadline - loop.time()))

    def _update_heading_status(self, now: float) -> None:
        """The heading state (daemon.heading_status) into the health (MAV_STATE, SYS_STATUS bits); the learned
        iron's parameters and periodic save (daemon.learned_iron)."""
        hs = self.heading_status
        if hs is not None and self.pipeline is not None:
            hs.on_estimate(self.pipeline.last_estimate, now, getattr(self.pipeline.estimator, "yaw_resets", 0))
            self.health.heading_good, self.health.heading_unhealthy_bits = hs.heading_good, hs.unhealthy_bits()
        if self.learned_iron is not None:
            self.learned_iron.tick(now)

    def _update_load(self, now: float) -> None:
        t0, cpu0 = self._cpu_window
        cpu = time.process_time()
        if now > t0:
            self.load_permille = int(1000.0 * (cpu - cpu0) / (now - t0))
        self._cpu_window = (now, cpu)
        t_prev, n_prev = self._rate_window
        n = self.pipeline.counters.samples
        if t_prev:
            self.measured_rate_hz = (n - n_prev) / (now - t_prev)
        self._rate_window = (now, n)

    def _on_state_change(self, old: int | None, new: int) -> None:
        name = STATE_NAMES.get(new, str(new))
        severity = {mavlink.MAV_STATE_CRITICAL: mavlink.MAV_SEVERITY_CRITICAL,
                    mavlink.MAV_STATE_ACTIVE: mavlink.MAV_SEVERITY_NOTICE}.get(new, mavlink.MAV_SEVERITY_INFO)
        detail = {
            mavlink.MAV_STATE_BOOT: "waiting for the sensor",
            mavlink.MAV_STATE_STANDBY: (self.heading_status.standby_detail() if self.heading_status is not None
                                        else "initialising, no heading out"),
            mavlink.MAV_STATE_ACTIVE: "heading good",
            mavlink.MAV_STATE_CALIBRATING: self.health.calibrating or "calibrating",
            mavlink.MAV_STATE_CRITICAL: self.health.sensor_error or "no samples from the sensor",
        }.get(new, "")
        self.statustext(severity, f"ahrsd: {name}: {detail}"[:50])   # "heading good": only when heading_status says so
        self.notifier.status(f"{name}: {detail}")

