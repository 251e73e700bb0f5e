"""Sensor alarms to the ground station: every new kind of DIAG_STAT alarm (EA flag) counted by the driver is
sent as one STATUSTEXT (at most one per kind per ALARM_REPORT_PERIOD_S), so the operator learns why samples are
flagged. (Start-up retries and bus reconnection: drivers.reconnecting.)"""

from __future__ import annotations

import asyncio

from ahrsd.daemon.mavlink_io import mavlink

ALARM_REPORT_PERIOD_S = 10.0
ALARM_CHECK_PERIOD_S = 0.5


async def report_sensor_alarms(service, period_s: float = ALARM_CHECK_PERIOD_S) -> None:
    """STATUSTEXT for new DIAG_STAT alarm kinds and start-up/bus failures counted by the driver."""
    seen: dict[str, int] = {}
    last_sent: dict[str, float] = {}
    while True:
        await asyncio.sleep(period_s)
        source = service.source
        counters = source.counters() if source is not None else {}
        now = service.clock()
        for key, value in counters.items():
            if not key.startswith("diag_") or value <= seen.get(key, 0):
                continue
            seen[key] = value
            if now - last_sent.get(key, -1e9) >= ALARM_REPORT_PERIOD_S:
                last_sent[key] = now
                service.statustext(mavlink.MAV_SEVERITY_WARNING, f"ahrsd: sensor alarm {key[5:].upper()}")
