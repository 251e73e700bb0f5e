"""The published heading state's hysteresis (estimator/heading_state_hold.py): a worse state at once, a better
one only after it held, UNKNOWN left only below the entry σ. Expected states are written out by hand."""

from __future__ import annotations

import math

import pytest

from ahrsd.core.estimate import HeadingState
from ahrsd.estimator.heading_state_hold import HeadingStateHold

U, G, L, M = HeadingState.UNKNOWN, HeadingState.GNSS_ONLY, HeadingState.LEARNING, HeadingState.MAGNETOMETER
HOLD_S = 5.0
ENTER = math.radians(12.0)
LOW, HOVER = math.radians(5.0), math.radians(14.5)

CASES = {
    # GNSS-only for 1 s, unknown for 0.2 s, GNSS-only again: published after 5 s of the second stretch only
    "a flicker is published once it held": (
        [(0.0, G, LOW), (1.0, U, LOW), (1.2, G, LOW), (4.0, G, LOW), (6.19, G, LOW), (6.2, G, LOW)],
        [U, U, U, U, U, G]),
    "a worse state at once": (
        [(0.0, M, LOW), (5.0, M, LOW), (5.1, L, LOW), (5.2, M, LOW), (5.3, U, LOW), (5.4, G, LOW)],
        [U, M, L, L, U, U]),
    # σ between the entry σ (12°) and the UNKNOWN limit (15°, the raw state's): UNKNOWN however long; below 12°
    # the hold starts; a published GNSS-only then stays while σ hovers above 12° again
    "unknown left only below the entry sigma": (
        [(0.0, G, HOVER), (10.0, G, HOVER), (20.0, G, LOW), (24.9, G, LOW), (25.0, G, LOW), (30.0, G, HOVER)],
        [U, U, U, U, G, G]),
    # a better state that gives way to another better one before it held: the hold starts again for the new one
    "the hold starts again when the waiting state changes": (
        [(0.0, G, LOW), (3.0, M, LOW), (5.0, M, LOW), (7.9, M, LOW), (8.0, M, LOW)],
        [U, U, U, U, M]),
    "an equally good other state waits too": (
        [(0.0, G, LOW), (5.0, G, LOW), (6.0, L, LOW), (7.0, G, LOW), (8.0, L, LOW), (13.0, L, LOW)],
        [U, G, G, G, G, L]),
}


@pytest.mark.parametrize("name", CASES)
def test_the_published_state(name):
    steps, expected = CASES[name]
    hold = HeadingStateHold(HOLD_S, ENTER)
    assert [hold.update(t, raw, sigma) for t, raw, sigma in steps] == expected
