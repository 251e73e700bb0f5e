"""The chip reader asks its sample timer once per fresh read (`fresh_if_certain`) what it asked twice before
(`index_uncertain`, then `fresh`): the answer and the timer's state after it must be those of the two questions,
read after read, on reads that leave the index certain and on reads that do not."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from ahrsd.drivers.chip_source import ADIS16405_RATE_HZ
from ahrsd.drivers.sample_timer import SampleTimer, StallAwareSampleTimer

P = 1.0 / ADIS16405_RATE_HZ


@pytest.mark.parametrize("make_timer", [SampleTimer, StallAwareSampleTimer])
def test_one_question_answers_as_the_two_did(make_timer):
    """A chip at phase φ read at the timer's next read time plus a drawn lateness, each read taking a drawn time
    (at times a large part of a period: a read that straddles a ready time). Two timers fed the same reads: one
    asked `index_uncertain` then `fresh` (the old protocol), one `fresh_if_certain`; where the index is uncertain
    both are then given the same chip answer (`fresh` at the read's end, as drivers.chip_source's check ends)."""
    rng = np.random.default_rng(7)
    two, one = make_timer(P), make_timer(P)
    phi = 10.0 + 0.37 * P
    t = phi + 0.2 * P
    k_read = -1
    certain = uncertain = stale = 0
    for _ in range(6000):
        t = max(t, two.next_read_time()) + rng.choice([20e-6, 0.1 * P, 0.3 * P, 1.5 * P], p=[0.7, 0.15, 0.1, 0.05])
        end = t + rng.choice([40e-6, 0.3 * P, 0.6 * P], p=[0.6, 0.25, 0.15])
        newest = math.floor((t - phi) / P)            # the chip's sample at the read's start
        if newest <= k_read:
            two.stale(t)
            one.stale(t)
            stale += 1
        else:
            k_read = newest
            if two.index_uncertain(t, end):
                assert one.fresh_if_certain(t, end) is None
                assert one.__dict__ == two.__dict__       # nothing changed by the question
                uncertain += 1
                assert one.fresh(end, end) == two.fresh(end, end)
            else:
                want = two.fresh(t, end)
                assert one.fresh_if_certain(t, end) == want
                certain += 1
        assert one.__dict__ == two.__dict__
        t = end
    assert certain > 3000 and uncertain > 50 and stale > 50


def test_the_first_read_is_fresh():
    """Before the first sample the bracket is open: the one question takes the sample (never uncertain)."""
    one, two = StallAwareSampleTimer(P), StallAwareSampleTimer(P)
    assert one.fresh_if_certain(5.0, 5.0 + 30e-6) == two.fresh(5.0, 5.0 + 30e-6)
    assert one.__dict__ == two.__dict__


def test_a_copy_is_what_the_question_leaves_when_uncertain():
    """An uncertain read leaves every bound and index as it was (the chip is asked next)."""
    timer = SampleTimer(P)
    timer.fresh(1.0, 1.0)
    for i in range(1, 40):
        timer.fresh(1.0 + i * P + 50e-6, 1.0 + i * P + 80e-6)
    before = copy.deepcopy(timer.__dict__)
    start = timer.next_read_time() + 0.2 * P
    end = start + 0.9 * P                                  # straddles a ready time
    assert timer.index_uncertain(start, end)
    assert timer.fresh_if_certain(start, end) is None
    assert timer.__dict__ == before
