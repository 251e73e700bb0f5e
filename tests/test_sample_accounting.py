"""The daemon tells apart the samples the chip produced but the estimator never got (missed), the ones it got
late, and the frames the driver rejected (corrupt): run_stats, SYS_STATUS errors_count2/3/4 and the status line."""

from __future__ import annotations

import time

import numpy as np

from ahrsd.core.sample import ImuSample, SampleFlags
from ahrsd.daemon.run_stats import collect_stats, sample_accounting
from ahrsd.daemon.sample_reader import LATE_AFTER_S
from ahrsd.daemon.status_line import format_status
from ahrsd.daemon.autopilot import AutopilotState
from ahrsd.drivers.source_interface import LiveSource

from service_rig import gcs_socket, start_service, stop_service

PERIOD_S = 1 / 819.2


class CountingSource(LiveSource):
    description = "test source"
    sample_rate_hz = 819.2
    per_sample = False
    monotonic_offset_s = 0.0

    def __init__(self, counters):
        self._counters = counters

    def counters(self):
        return dict(self._counters)

    def poll(self):
        return []

    def close(self):
        pass


def sample(k: int, t_s: float, flags=SampleFlags.NEW_DATA) -> ImuSample:
    return ImuSample(t_s, np.zeros(3), np.array([0.0, 0.0, -9.81]), np.array([20.0, 0.0, 40.0]), 25.0, 5.0,
                     flags, 0, k)


def test_missed_late_and_corrupt_are_counted_apart(tmp_path):
    gcs = gcs_socket()
    service, loop = start_service(gcs, tmp_path)
    try:
        service.source = service.reader.source = CountingSource(
            {"garbage_frames": 2, "short_reads": 1, "stale_reads": 50})
        now = time.monotonic()
        old = now - 4 * LATE_AFTER_S
        block = [sample(k, old + k * PERIOD_S) for k in range(5)]                      # 5 late
        block.append(sample(8, now - 0.2 * LATE_AFTER_S, SampleFlags.NEW_DATA | SampleFlags.GAP_BEFORE))  # 3 missed
        service.reader.process(block, now)
        assert sample_accounting(service) == {"delivered": 6, "missed": 3, "late": 5, "corrupt": 3}
        assert collect_stats(service)["samples"]["late"] == 5
        m = service.sys_status_message(now)
        assert (m.errors_count2, m.errors_count3, m.errors_count4) == (3, 5, 3)
        line = format_status(estimate=None, rate_hz=819.2, state=0, samples=sample_accounting(service),
                             link={"tx": 1, "rx": 2, "bad": 0}, gnss=None, autopilot=AutopilotState())
        assert "missed 3 late 5 corrupt 3 tx 1" in line
        service.counters.driver_errors += 1                                            # a bus failure
        assert service.sys_status_message(now).errors_count4 == 4
    finally:
        stop_service(service, loop)
        gcs.close()
