"""The reader's pacing waits with time.sleep itself when no `sleep_until` is given (drivers.threaded_source._Pacing,
the reader process's case): the read times it waits for, the stale re-reads it spaces and the lateness it counts
are those of the general wait (`_wait_until` with a given sleep_until), wake after wake."""

from __future__ import annotations

import numpy as np

from ahrsd.drivers import threaded_source
from ahrsd.drivers.threaded_source import _Pacing

PERIOD_S = 1.0 / 819.2


class _Clock:
    def __init__(self):
        self.t = 50.0

    def __call__(self) -> float:
        return self.t


class _Timer:
    """A SampleTimer's next read times: a period apart, from the clock's start."""

    waits_for_edges = False

    def __init__(self):
        self.k = 0

    def next_read_time(self) -> float:
        return 50.0 + self.k * PERIOD_S


class _Inner:
    def __init__(self):
        self.timer = _Timer()


def _run(own_sleep: bool, monkeypatch) -> tuple[list[float], dict]:
    """Wakes of one pacing on a stepped clock: each wait returns after a drawn lateness (mostly µs, at times a
    quarter period or more than a period); every 7th read is stale (the timer's read time then does not move)."""
    rng = np.random.default_rng(11)
    clock, inner = _Clock(), _Inner()
    stats = {"wakes_late": 0, "wakes_late_quarter": 0, "wake_late_max_us": 0, "stale_rereads_spaced": 0}

    def late() -> float:
        return float(rng.choice([5e-6, 40e-6, 0.3 * PERIOD_S, 1.4 * PERIOD_S], p=[0.6, 0.3, 0.07, 0.03]))

    def sleep(dt: float) -> None:                   # time.sleep on the stepped clock
        clock.t += dt + late()

    def sleep_until(t: float) -> None:             # threaded_source._sleep_until on the stepped clock
        if t > clock.t:
            sleep(t - clock.t)

    if own_sleep:
        monkeypatch.setattr(threaded_source.time, "sleep", sleep)
    pacing = _Pacing(inner, clock, None if own_sleep else sleep_until, PERIOD_S, stats,
                     sleep_until_default=sleep_until)
    wakes = []
    for i in range(3000):
        assert pacing.wait_for_sample() is True
        wakes.append(clock.t)
        pacing.last_read_s = clock.t
        pacing.last_stale = i % 7 == 3
        if not pacing.last_stale:
            inner.timer.k += 1
        clock.t += 30e-6
    return wakes, stats


def test_own_sleep_wakes_and_counts_as_the_general_wait(monkeypatch):
    general_wakes, general = _run(False, monkeypatch)
    own_wakes, own = _run(True, monkeypatch)
    assert own_wakes == general_wakes
    assert own == general
    # the draws reach every count: quarter-late and period-late wakes, spaced re-reads
    assert general["wakes_late"] > 20 and general["wakes_late_quarter"] > general["wakes_late"] + 20
    assert general["stale_rereads_spaced"] > 20
