"""The daemon's default output rates on a stepped clock: a Service built from the default configuration, its
UDP endpoint's output schedule woken once per ADIS16405 sample (819.2 Hz) for 20 s of simulated time. The
rates are the documented defaults (docs/mavlink.md, the `[outputs]` keys): ATTITUDE 50 Hz, ATTITUDE_QUATERNION
10, VISION_POSITION_ESTIMATE 30, HIGHRES_IMU 10, SYS_STATUS 1; SCALED_IMU and the navigation outputs off. The
real-time check of the running daemon (tests/test_integration_daemon.py) only bounds them, with room for a
loaded machine."""

from __future__ import annotations

from collections import Counter

import pytest

from ahrsd.daemon.mavlink_io import mavlink
from service_rig import gcs_socket, start_service, stop_service

DEFAULT_HZ = {
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 50.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 10.0,
    mavlink.MAVLINK_MSG_ID_VISION_POSITION_ESTIMATE: 30.0,
    mavlink.MAVLINK_MSG_ID_HIGHRES_IMU: 10.0,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
}


@pytest.mark.parametrize("wake_period_s", [1 / 819.2, 0.0031], ids=["every-sample", "every-3.1ms"])
def test_default_output_rates_on_a_stepped_clock(tmp_path, wake_period_s):
    gcs = gcs_socket()
    service, loop = start_service(gcs, tmp_path / "state")
    try:
        schedule = service.endpoints[0].schedule
        counts: Counter = Counter()
        duration_s, k = 20.0, 0
        while (now := 1000.0 + k * wake_period_s) < 1000.0 + duration_s:
            counts.update(schedule.due(now))
            k += 1
    finally:
        stop_service(service, loop)
        gcs.close()
    for mid, hz in DEFAULT_HZ.items():
        assert counts[mid] == pytest.approx(hz * duration_s, abs=1), mavlink.mavlink_map[mid].msgname
    assert set(counts) == set(DEFAULT_HZ), sorted(mavlink.mavlink_map[m].msgname for m in counts)
