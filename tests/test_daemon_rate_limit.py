"""STATUSTEXTs that remote input can trigger are rate limited; critical ones always go out."""

from __future__ import annotations

from ahrsd.daemon.counters import ServiceCounters
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.outbound import Identity, Outbound
from ahrsd.daemon.rate_limit import TokenBucket
from support.kept_link import KeptLink


def test_token_bucket_allows_the_burst_then_the_rate():
    bucket = TokenBucket(rate_per_s=5.0, burst=10)
    assert sum(bucket.take(0.0) for _ in range(100)) == 10      # the burst, then nothing at the same instant
    assert sum(bucket.take(1.0) for _ in range(100)) == 5       # one second refills five
    assert not bucket.take(1.0)
    assert bucket.take(1.25)                                    # 0.25 s refills more than one token


def test_statustext_flood_is_bounded_and_counted():
    """The outbound part alone, on a stepped clock: the burst goes out, the rest is counted; one second later
    the rate refills; a critical text always goes out."""
    clock = [100.0]
    counters = ServiceCounters()
    outbound = Outbound(Identity(1, 191, mavlink.MAV_TYPE_ONBOARD_CONTROLLER), counters, clock=lambda: clock[0])
    link = KeptLink()
    sent = link.sent
    outbound.endpoints.append(link)
    for k in range(1000):                                       # e.g. a flood of refused parameter writes
        outbound.statustext(mavlink.MAV_SEVERITY_WARNING, f"ahrsd: unknown parameter X{k}")
    assert len(sent) == 10                                      # the burst
    assert counters.statustext_suppressed == 990
    clock[0] += 1.0
    for k in range(100):
        outbound.statustext(mavlink.MAV_SEVERITY_WARNING, f"ahrsd: unknown parameter Y{k}")
    assert len(sent) == 15 and counters.statustext_suppressed == 1085      # 5/s refilled
    outbound.statustext(mavlink.MAV_SEVERITY_CRITICAL, "ahrsd: sensor failure: test")
    assert len(sent) == 16                                      # critical texts are never dropped
    assert sent[-1].text == "ahrsd: sensor failure: test"
