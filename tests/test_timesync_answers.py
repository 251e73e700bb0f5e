"""TIMESYNC requests are answered per sender up to a rate (daemon.timesync_answers), on a stepped clock: a real
requester is never refused, a flood is bounded, counted and logged."""

from __future__ import annotations

import logging
import math

from ahrsd.daemon import timesync_answers as ta
from ahrsd.daemon.counters import ServiceCounters
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.timesync_answers import TimesyncAnswers
from support.kept_link import KeptLink
from support.mavlink_feed import as_if_from

STAMP_NS = 123_456_789


class Link(KeptLink):
    """What TimesyncAnswers needs of an endpoint: send, and the tc1 stamp of the request being handled."""

    def timesync_stamp_ns(self) -> int:
        return STAMP_NS


def request(ts1: int, sysid: int = 1, compid: int = 1):
    return as_if_from(mavlink.MAVLink_timesync_message(0, ts1), sysid, compid)


def test_a_flood_at_one_instant_gets_the_burst_then_the_rate():
    counters = ServiceCounters()
    answers, link = TimesyncAnswers(counters), Link()
    for k in range(1000):
        answers.on_request(link, request(1000 + k), 50.0)
    assert [m.ts1 for m in link.sent] == list(range(1000, 1020))        # the first 20, ts1 mirrored
    assert all(m.tc1 == STAMP_NS for m in link.sent)
    assert counters.timesync_refused == 980 and counters.timesync_answered == 20
    for k in range(1000):
        answers.on_request(link, request(5000 + k), 51.0)               # one second refills 20
    assert len(link.sent) == counters.timesync_answered == 40 and counters.timesync_refused == 1960


def test_a_real_requester_beside_a_flood_loses_nothing():
    """PX4's 10 Hz from the autopilot (1/1) and 1000/s from a flooding peer (7/190) on the same link, 10 s in
    1 ms steps: the autopilot gets all its 100 answers, the flood the burst and 20/s."""
    counters = ServiceCounters()
    answers, link = TimesyncAnswers(counters), Link()
    for ms in range(10_000):
        now = 1000.0 + ms * 1e-3
        if ms % 100 == 0:
            answers.on_request(link, request(ms, 1, 1), now)
        answers.on_request(link, request(-ms - 1, 7, 190), now)
    autopilot = [m for m in link.sent if m.ts1 >= 0]
    flood = [m for m in link.sent if m.ts1 < 0]
    assert len(autopilot) == 100
    expected_flood = 20 + math.floor(9.999 * 20)                       # the burst, then one per 50 ms
    assert abs(len(flood) - expected_flood) <= 1
    assert counters.timesync_refused == 10_000 - len(flood)


def test_each_endpoint_has_its_own_limit():
    answers, a, b = TimesyncAnswers(ServiceCounters()), Link(), Link()
    for k in range(100):
        answers.on_request(a, request(k), 0.0)
        answers.on_request(b, request(k), 0.0)
    assert len(a.sent) == len(b.sent) == 20


def test_refusals_are_logged_at_the_first_then_once_a_minute(caplog):
    answers, link = TimesyncAnswers(ServiceCounters()), Link()
    with caplog.at_level(logging.WARNING, logger="ahrsd.daemon.timesync_answers"):
        for ms in range(0, 61_000, 10):                                  # 100/s for 61 s
            answers.on_request(link, request(ms, 7, 190), ms * 1e-3)
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 2, lines
    assert "7/190" in lines[0] and ": 1 not answered" in lines[0]
    # the second, 60 s after the first: what was refused since, 80 of the 100 requests a second
    refused_since = int(lines[1].split(": ")[1].split(" ")[0])
    assert abs(refused_since - 60 * 80) <= 2, lines[1]


def test_forged_sender_ids_share_one_limit_beyond_the_followed_ones():
    counters = ServiceCounters()
    answers, link = TimesyncAnswers(counters), Link()
    for sysid in range(1, 1001):
        for _ in range(3):
            answers.on_request(link, request(sysid, sysid % 256, sysid // 256), 0.0)
    # the first MAX_SENDERS senders each get their 3 (within the burst), the rest share one burst of 20
    assert len(link.sent) == 3 * ta.MAX_SENDERS + ta.BURST
    assert len(answers._senders) == ta.MAX_SENDERS + 1
