"""bench/wake_floor.py `--compiled`: the bare loop in C sleeps to the same absolute sample times as the Python loop,
so its CPU a wake is the interpreter-free floor of a reader that wakes once a sample.

The truth is counts and a bound that load cannot break: the loop makes exactly `seconds / period` wakes, and a loop
that sleeps to absolute times k·period after its start cannot end before the last one (a busy machine only makes it
later). A loop that slept for shorter steps, or fewer of them, would not be the floor of a reader at that rate."""

from __future__ import annotations

import shutil

import pytest

from bench.wake_floor import compiled_wake_lateness

pytestmark = pytest.mark.skipif(shutil.which("cc") is None and shutil.which("gcc") is None,
                                reason="no C compiler for bench/wake_floor.py --compiled")


def test_the_c_loop_wakes_once_a_period_and_never_before_its_sample_times():
    period_s = 0.004
    r = compiled_wake_lateness(0.2, period_s=period_s)
    assert r["wakes"] == 50                        # 0.2 s / 4 ms
    assert r["wall_s"] >= 0.999 * 50 * period_s    # the 50th sample time is 200 ms after the start
    assert 0 <= r["late"] <= r["late_quarter"] <= r["wakes"]
    assert r["cpu_s"] > 0.0 and r["cpu_share"] == pytest.approx(r["cpu_s"] / 0.2)
