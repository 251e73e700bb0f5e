"""Timing faults below the daemon: a reader frozen 0.1–2 s (CPU starvation), clock jumps, repeated and
backwards time stamps. The end-to-end SIGSTOP/SIGCONT runs are in test_reliability_daemon.py; the MEKF's own
gap flags in test_mekf.py (extended here with what the autopilot sees: the 1σ it is told)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ahrsd.drivers.chip_source import ADIS16405_RATE_HZ
from ahrsd.drivers.sample_timer import StallAwareSampleTimer
from ahrsd.core.sample import make_sample
from ahrsd.estimator import make_estimator
from ahrsd.core.estimate import EstimateFlags

P = 1.0 / ADIS16405_RATE_HZ
G0 = 9.80665


@settings(derandomize=True, deadline=None, max_examples=60)
@given(st.floats(0.1, 2.0), st.floats(0.0, 1.0), st.floats(0.0, 0.9))
def test_a_frozen_reader_counts_the_samples_it_missed(freeze_s, phase, late):
    """The daemon's read schedule (read at next_read_time(); a read before the next sample is ready is
    stale) locks on the chip's phase; then the process freezes for freeze_s and the first read after it comes
    `late` of a period after a sample boundary: the gap is counted and t_s is on the sample grid."""
    timer = StallAwareSampleTimer(P)
    phi = 50.0 + phase * P
    T, k_last, k_first = phi + 0.3 * P, -1, None
    while k_last < 800:                                        # ~1 s of normal reading
        newest = math.floor((T - phi) / P)
        if newest > k_last:
            t, k, lost = timer.fresh(T)
            k_first = newest - k if k_first is None else k_first
            assert k + k_first == newest
            k_last = newest
        else:
            timer.stale(T)
        T = max(timer.next_read_time(), T + 1e-6)
    wake = phi + math.floor((T + freeze_s - phi) / P) * P + late * P
    k_chip = math.floor((wake - phi) / P)
    t, k, lost = timer.fresh(wake)
    # the chip has no sample counter: after a freeze the phase bracket has leaked to about a period, so the
    # index can be one too high (a phantom loss, docs/reliability.md) but never too low (a silent loss)
    true_lost = k_chip - k_last - 1
    assert true_lost <= lost <= true_lost + 1
    assert k + k_first - k_chip in (0, 1)
    assert -100e-6 < t - (phi + k_chip * P) < P                # stamped within a period of the true sample time


def _static(t):
    return make_sample(t, [0.0, 0.0, 0.0], [0.0, 0.0, -G0], [20.0, 0.0, 45.0])


def test_heading_uncertainty_grows_over_a_gap_and_the_gap_is_reported():
    est = make_estimator("mekf")
    t = 0.0
    for _ in range(int(8 * ADIS16405_RATE_HZ)):
        out = est.update(_static(t))
        t += P
    before = float(out.sigma_rpy_rad[2])
    assert not out.flags & EstimateFlags.INITIALISING
    out = est.update(_static(t + 1.5))                         # 1.5 s starved: propagated, not re-initialised
    assert out.flags & EstimateFlags.LARGE_DT and not out.flags & EstimateFlags.REINITIALISED
    assert float(out.sigma_rpy_rad[2]) > before                # the autopilot is told the heading is less sure
    out = est.update(_static(t + 1.5 + 2.5))                  # 2.5 s more: re-initialised, INITIALISING
    assert out.flags & EstimateFlags.REINITIALISED and out.flags & EstimateFlags.INITIALISING


def test_repeated_and_backwards_time_stamps_never_break_the_estimate():
    est = make_estimator("mekf")
    t = 0.0
    for _ in range(int(3 * ADIS16405_RATE_HZ)):
        out = est.update(_static(t))
        t += P
    q = out.q_wxyz.copy()
    last = t - P
    for dt in (0.0, -P, -0.5, -1e6):                            # a repeated stamp / the clock stepped back
        out = est.update(_static(last + dt))
        assert out.flags & EstimateFlags.LARGE_DT
        assert np.all(np.isfinite(out.q_wxyz)) and abs(np.linalg.norm(out.q_wxyz) - 1.0) < 1e-9
    assert np.degrees(2 * math.acos(min(1.0, abs(float(np.dot(q, out.q_wxyz)))))) < 0.5   # no jump
    out = est.update(_static(t + P))
    assert np.all(np.isfinite(out.q_wxyz))


@pytest.mark.parametrize("stall_periods", [5, 40])
def test_a_stall_right_after_the_first_sample_keeps_the_phase(stall_periods):
    """The chip's data-ready stalls just after its first sample (ND clear on every read for `stall_periods`
    periods): the stale reads meanwhile are taken as a stall, not as a phase error (StallAwareSampleTimer goes back
    to the bracket of the last fresh read — here the first one's), so the first sample after the stall gets the
    index its time says, counting the samples the stall cost."""
    timer = StallAwareSampleTimer(P)
    phi = 50.0 + 0.4 * P                       # sample k is ready at phi + k P
    T = phi + 0.3 * P
    t, k, lost = timer.fresh(T)                # sample 0
    assert (k, lost) == (0, 0)
    resume = phi + stall_periods * P           # the chip's next new sample: index `stall_periods`
    T = max(timer.next_read_time(), T + 1e-6)
    while T < resume:
        timer.stale(T)
        T = max(timer.next_read_time(), T + 1e-6)
    newest = math.floor((T - phi) / P)
    t, k, lost = timer.fresh(T)
    assert k == newest and lost == newest - 1
    assert -100e-6 < t - (phi + newest * P) < P
