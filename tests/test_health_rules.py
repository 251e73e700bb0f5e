"""daemon.health's rules, case by case, against the rule as docs/reliability.md states it (not against the code):
the autopilot gets our heading only from an initialised estimator on a working sensor; SYS_STATUS's 3D_MAG and
AHRS health bits are cleared while the magnetometer is unavailable (gyro-only heading); HEARTBEAT's state is
BOOT, STANDBY (initialising, heading not good), CALIBRATING, ACTIVE or CRITICAL."""

from __future__ import annotations

import pytest

from ahrsd.core.estimate import EstimateFlags
from ahrsd.daemon.health import Health
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.messages import SENSOR_ACCEL, SENSOR_AHRS, SENSOR_GYRO, SENSOR_MAG

STALE_S = 0.1
ALL = SENSOR_GYRO | SENSOR_ACCEL | SENSOR_MAG | SENSOR_AHRS


def _health(flags: EstimateFlags | None, *, sample_at: float | None = 1.0, sensor_error: str = "",
            calibrating: str = "", heading_good: bool = True) -> Health:
    h = Health(stale_timeout_s=STALE_S, last_estimate_flags=flags, sensor_error=sensor_error, calibrating=calibrating,
               heading_good=heading_good)
    if sample_at is not None:
        h.sample_read(sample_at)
    return h


@pytest.mark.parametrize("flags, error, trusted", [
    (EstimateFlags.NONE, "", True),
    (EstimateFlags.INITIALISING, "", False),                 # an estimator still initialising
    (EstimateFlags.INITIALISING | EstimateFlags.MAG_UNAVAILABLE, "", False),
    (EstimateFlags.MAG_UNAVAILABLE, "", True),               # gyro-only heading: sent, with its growing σ
    (None, "", False),                                       # no estimate yet
    (EstimateFlags.NONE, "bus error", False),                # a failed sensor
], ids=["initialised", "initialising", "initialising-magless", "magless", "no-estimate", "sensor-failed"])
def test_the_autopilot_gets_a_heading_only_from_an_initialised_estimator_on_a_working_sensor(flags, error, trusted):
    assert _health(flags, sensor_error=error).heading_trusted(1.05) is trusted


def test_the_heading_is_not_trusted_once_samples_stop():
    h = _health(EstimateFlags.NONE)
    h.empty_read(1.0 + 2 * STALE_S)                          # the reader looked and found none, overdue
    assert not h.heading_trusted(1.0 + 2 * STALE_S)


@pytest.mark.parametrize("flags, healthy", [
    (EstimateFlags.NONE, ALL),
    (EstimateFlags.MAG_UNAVAILABLE, SENSOR_GYRO | SENSOR_ACCEL),   # neither 3D_MAG nor AHRS
    (EstimateFlags.INITIALISING, SENSOR_GYRO | SENSOR_ACCEL | SENSOR_MAG),   # AHRS not yet
], ids=["good", "magless", "initialising"])
def test_sys_status_health_bits(flags, healthy):
    present, enabled, health = _health(flags).sensor_bits(1.05)
    assert present == enabled == ALL
    assert health == healthy


def test_the_heading_status_clears_the_bits_it_names():
    h = _health(EstimateFlags.NONE)
    h.heading_unhealthy_bits = SENSOR_MAG
    assert h.sensor_bits(1.05)[2] == SENSOR_GYRO | SENSOR_ACCEL | SENSOR_AHRS


@pytest.mark.parametrize("kw, state", [
    (dict(flags=None, sample_at=None), mavlink.MAV_STATE_BOOT),
    (dict(flags=EstimateFlags.INITIALISING), mavlink.MAV_STATE_STANDBY),
    (dict(flags=EstimateFlags.NONE, heading_good=False), mavlink.MAV_STATE_STANDBY),
    (dict(flags=EstimateFlags.NONE, calibrating="mag"), mavlink.MAV_STATE_CALIBRATING),
    (dict(flags=EstimateFlags.NONE, sensor_error="bus error"), mavlink.MAV_STATE_CRITICAL),
    (dict(flags=EstimateFlags.NONE), mavlink.MAV_STATE_ACTIVE),
], ids=["boot", "initialising", "heading-not-good", "calibrating", "sensor-failed", "active"])
def test_heartbeat_state(kw, state):
    flags = kw.pop("flags")
    assert _health(flags, **kw).system_status(1.05) == state
