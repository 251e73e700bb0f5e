"""daemon.sensor_recovery.report_sensor_alarms: one STATUSTEXT per new DIAG_STAT alarm kind, at most one per kind per
ALARM_REPORT_PERIOD_S of the daemon's clock (Service.clock), stepped here: no wall time decides what is sent."""

from __future__ import annotations

import asyncio
from types import SimpleNamespace

from ahrsd.daemon.sensor_recovery import ALARM_REPORT_PERIOD_S, report_sensor_alarms


def test_a_recurring_alarm_is_reported_once_per_period_of_the_daemons_clock():
    now_s = [0.0]
    counters = {"diag_flash_update": 0, "diag_power_low": 0, "samples": 5}
    texts = []
    steps = [  # (clock s, counters changed) before each check of the task
        (0.0, {"diag_flash_update": 1}),                      # new kind: reported
        (1.0, {"diag_flash_update": 2}),                      # again within the period: not reported
        (2.0, {"diag_power_low": 1, "samples": 9}),           # another kind: reported; non-diag counters never
        (ALARM_REPORT_PERIOD_S - 0.5, {"diag_flash_update": 3}),   # 9.5 s after the first: still not
        (ALARM_REPORT_PERIOD_S, {"diag_flash_update": 4}),   # a period after the first report: reported
        (ALARM_REPORT_PERIOD_S + 1.0, {}),                    # no new count: nothing
    ]
    service = SimpleNamespace(clock=lambda: now_s[0], source=SimpleNamespace(counters=lambda: dict(counters)),
                              statustext=lambda severity, text: texts.append((now_s[0], text)))

    async def run():
        task = asyncio.get_running_loop().create_task(report_sensor_alarms(service, period_s=0.0))
        for t, changes in steps:
            now_s[0] = t
            counters.update(changes)
            for _ in range(3):                 # let the task run its check (asyncio.sleep(0) yields once)
                await asyncio.sleep(0)
        task.cancel()

    asyncio.run(run())
    assert texts == [(0.0, "ahrsd: sensor alarm FLASH_UPDATE"), (2.0, "ahrsd: sensor alarm POWER_LOW"),
                     (ALARM_REPORT_PERIOD_S, "ahrsd: sensor alarm FLASH_UPDATE")]
