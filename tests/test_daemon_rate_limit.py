"""STATUSTEXTs that remote input can trigger are rate limited; critical ones always go out."""

from __future__ import annotations

import dataclasses as dc

from ahrsd.daemon.config import Config, SensorConfig, StateConfig
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.rate_limit import TokenBucket
from ahrsd.daemon.service import Service


def test_token_bucket_allows_the_burst_then_the_rate():
    bucket = TokenBucket(rate_per_s=5.0, burst=10)
    assert sum(bucket.take(0.0) for _ in range(100)) == 10      # the burst, then nothing at the same instant
    assert sum(bucket.take(1.0) for _ in range(100)) == 5       # one second refills five
    assert not bucket.take(1.0)
    assert bucket.take(1.25)                                    # 0.25 s refills more than one token


def test_service_statustext_flood_is_bounded_and_counted(tmp_path):
    cfg = dc.replace(Config(), state=StateConfig(str(tmp_path)), sensor=SensorConfig(source="spi"))
    svc = Service(cfg)
    sent = []
    svc.send = lambda msg, endpoint=None: sent.append(msg)     # capture instead of a socket
    for k in range(1000):                                       # e.g. a flood of refused parameter writes
        svc.statustext(mavlink.MAV_SEVERITY_WARNING, f"ahrsd: unknown parameter X{k}")
    assert 10 <= len(sent) <= 20                                # the burst plus what the clock refilled
    assert svc.counters.statustext_suppressed == 1000 - len(sent)
    before = len(sent)
    svc.statustext(mavlink.MAV_SEVERITY_CRITICAL, "ahrsd: sensor failure: test")
    assert len(sent) == before + 1                              # critical texts are never dropped
