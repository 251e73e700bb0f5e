"""A real Signal K server (signalk-server from the npm registry) reads ahrsd's NMEA 0183 output: its own
parser turns our sentences into navigation.headingTrue, headingMagnetic, rateOfTurn and attitude with the
values, units and signs Signal K defines, at the configured rates (bench/signalk.py runs the same check longer).
Skips with the reason when Node.js or the server package cannot be had."""

from __future__ import annotations

import pytest

import math
from types import SimpleNamespace

from bench.signalk import PATHS, SignalKUnavailable, compare, ensure_server, run_check

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def reports():
    try:
        ensure_server(log=lambda *_: None)
    except SignalKUnavailable as exc:
        pytest.skip(f"no Signal K server here: {exc}")
    # 8 s, then on until every path has 40 updates (8 s of the slowest, 5 Hz): under load the stream's start can eat
    # part of a fixed window, and the checks below are on counts and the updates' own span
    return {r.path: r for r in run_check(seconds=8.0, log=lambda *_: None, min_updates=40)}


def test_signal_k_shows_every_path_with_our_values(reports):
    assert set(reports) == set(PATHS)
    # Signal K's updates against ahrsd's sentences in the same span, per path: all updates at 0 with sentences
    # sent says the stream failed, not one path; a path's sentences at 0 says ahrsd withheld it. The run's notes
    # say how the stream ended and what ahrsd logged last.
    counts = {path: f"{r.updates} of {r.sent} sent" for path, r in reports.items()}
    for path, r in reports.items():
        assert r.updates >= 30, f"{path}: updates of sentences sent {counts}; {r.run_notes}"
        assert r.matched == r.updates, (path, r)            # every update is one of our sentences
        assert r.max_difference < 1e-6, (path, r)           # same value, Signal K's units (rad, rad/s)
        assert r.rest_difference < 1e-6, (path, r)          # and what its REST API serves


def test_signal_k_updates_at_our_rates(reports):
    # HDG also gives Signal K a true heading (magnetic + variation): two 10 Hz sources of headingTrue
    expected_hz = {"navigation.headingTrue": 20.0, "navigation.headingMagnetic": 10.0,
                   "navigation.rateOfTurn": 5.0, "navigation.attitude": 5.0}
    for path, hz in expected_hz.items():
        assert reports[path].rate_hz == pytest.approx(hz, rel=0.2), (path, reports[path])


def test_an_update_a_loaded_server_delivers_late_is_still_its_sentence():
    """compare() without a server: HDT at 10 Hz (0.1° steps) of a heading turning 9 °/s, Signal K's updates of them
    arriving 3 s late (a server on a loaded machine) are each their own sentence; the same updates with a sign or a
    unit wrong, or 0.5° off, find no sentence of their value."""
    sent = [(0.1 * k, round(9.0 * 0.1 * k % 360.0, 1)) for k in range(300)]
    sentences = [(t, SimpleNamespace(msgID="HDT", headingT=deg)) for t, deg in sent]

    def report(value_of):
        updates = [(t + 3.0, "navigation.headingTrue", value_of(deg)) for t, deg in sent]
        return next(r for r in compare(updates, sentences, 30.0) if r.path == "navigation.headingTrue")

    late = report(math.radians)
    assert late.matched == late.updates == 300 and late.max_difference < 1e-9, late
    for wrong in (lambda deg: -math.radians(deg), lambda deg: deg, lambda deg: math.radians(deg + 0.5)):
        r = report(wrong)
        assert r.matched == r.updates == 300 and r.max_difference > 1e-3, r
