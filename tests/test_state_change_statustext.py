"""The STATUSTEXT the daemon sends on a MAV_STATE change reaches the ground station whole, however long its
detail: heading_status's STANDBY cause made it 68 characters, and a single STATUSTEXT holds 50."""

from __future__ import annotations

from ahrsd.core.estimate import EstimateFlags
from ahrsd.daemon.counters import ServiceCounters
from ahrsd.daemon.health import Health
from ahrsd.daemon.housekeeping import HealthReport
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.outbound import Identity, Outbound
from support.health_report_fakes import Counts, Notifier
from support.kept_link import KeptLink

STANDBY_DETAIL = "heading unknown (mag not calibrated), no heading out"   # daemon.heading_status's words


def _text(msg) -> str:
    t = msg.text
    return (t.decode("ascii") if isinstance(t, bytes) else t).rstrip("\0")


def test_the_standby_statustext_with_a_long_cause_arrives_whole_in_chunks():
    link = KeptLink()
    outbound = Outbound(Identity(1, 200, mavlink.MAV_TYPE_IMU), ServiceCounters(), clock=lambda: 0.0)
    outbound.endpoints.append(link)
    health = Health(stale_timeout_s=1.0)
    notifier = Notifier()
    report = HealthReport(health, outbound, notifier, Counts(), watchdog_interval_s=None, start=0.0,
                          standby_detail=lambda: STANDBY_DETAIL)
    health.sample_read(0.0)
    health.last_estimate_flags = EstimateFlags.NONE      # an estimate, not initialising ...
    health.heading_good = False                          # ... whose heading is not good: STANDBY
    report(0.0)
    texts = [m for m in link.sent if m.get_type() == "STATUSTEXT"]
    expected = "ahrsd: STANDBY: " + STANDBY_DETAIL
    assert len(expected) > 50
    # MAVLink 2 chunks (docs/daemon.md "Heading state"): one id, chunk_seq 0, 1, … in order, joined by the receiver
    assert len({m.id for m in texts}) == 1 and texts[0].id != 0
    assert [m.chunk_seq for m in texts] == list(range(len(texts)))
    assert "".join(_text(m) for m in texts) == expected
    assert notifier.statuses == ["STANDBY: " + STANDBY_DETAIL]


def test_a_short_state_change_is_still_one_plain_statustext():
    link = KeptLink()
    outbound = Outbound(Identity(1, 200, mavlink.MAV_TYPE_IMU), ServiceCounters(), clock=lambda: 0.0)
    outbound.endpoints.append(link)
    report = HealthReport(Health(stale_timeout_s=1.0), outbound, Notifier(), Counts(), watchdog_interval_s=None,
                          start=0.0)
    report(0.0)                                          # no estimate yet: BOOT
    texts = [m for m in link.sent if m.get_type() == "STATUSTEXT"]
    assert [(_text(m), m.id) for m in texts] == [("ahrsd: BOOT: waiting for the sensor", 0)]


def test_the_critical_state_is_said_at_critical_severity_even_through_a_flood():
    """MAV_STATE CRITICAL (the sensor failed) is announced at MAV_SEVERITY_CRITICAL, which the STATUSTEXT rate
    limit never holds back (daemon.outbound) and ground stations speak aloud: it reaches the operator even while a
    peer's refused requests have used up the budget."""
    link = KeptLink()
    counters = ServiceCounters()
    outbound = Outbound(Identity(1, 200, mavlink.MAV_TYPE_IMU), counters, clock=lambda: 0.0)
    outbound.endpoints.append(link)
    health = Health(stale_timeout_s=1.0)
    report = HealthReport(health, outbound, Notifier(), Counts(), watchdog_interval_s=None, start=0.0)
    for _ in range(20):
        outbound.statustext(mavlink.MAV_SEVERITY_WARNING, "ahrsd: unknown parameter X")
    assert counters.statustext_suppressed == 10
    health.sensor_error = "bus failure"
    report(0.0)
    (critical,) = [m for m in link.sent if m.get_type() == "STATUSTEXT" and "CRITICAL" in _text(m)]
    assert critical.severity == mavlink.MAV_SEVERITY_CRITICAL and _text(critical) == "ahrsd: CRITICAL: bus failure"
