"""Motion profiles: the angle is the exact integral of the rate, continuous across segments and periods."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from ahrsd.simulation.profiles import RateProfile, Segment, hold, ramp, smoothstep

@st.composite
def chained_segments(draw):
    """Segments whose rates chain (each starts where the previous ended, the last ends where the first starts)."""
    k = draw(st.integers(1, 6))
    rates = draw(st.lists(st.floats(-3.0, 3.0), min_size=k, max_size=k))
    durs = draw(st.lists(st.floats(0.1, 20.0), min_size=k, max_size=k))
    return [Segment(durs[i], rates[i], rates[(i + 1) % k]) for i in range(k)]


@settings(derandomize=True, max_examples=60, deadline=None)
@given(segs=chained_segments(), angle0=st.floats(-10, 10))
def test_angle_derivative_is_the_rate_and_both_are_continuous(segs, angle0):
    prof = RateProfile(segs, angle0=angle0)
    t = np.linspace(0.0, 2.5 * prof.period_s, 4001)
    h = 1e-6 * prof.period_s
    numeric = (prof.angle(t + h) - prof.angle(t - h)) / (2 * h)
    np.testing.assert_allclose(numeric, prof.rate(t), rtol=1e-5, atol=1e-5)
    # no jumps in the rate at segment boundaries or at the period wrap
    bounds = np.concatenate([np.cumsum([s.duration_s for s in segs]), 2 * prof.period_s + np.cumsum(
        [s.duration_s for s in segs])])
    eps = 1e-9 * prof.period_s
    np.testing.assert_allclose(prof.rate(bounds - eps), prof.rate(bounds + eps), atol=1e-6)
    assert prof.angle(np.array([0.0]))[0] == pytest.approx(angle0)
    assert prof.angle(np.array([prof.period_s]))[0] - angle0 == pytest.approx(prof.angle_per_period, abs=1e-9)


def test_ramp_integral_is_the_mean_rate_times_duration():
    prof = RateProfile([ramp(2.0, 0.0, 1.0), hold(3.0, 1.0), ramp(2.0, 1.0, 0.0)])
    assert prof.angle(np.array([2.0]))[0] == pytest.approx(1.0)
    assert prof.angle(np.array([7.0]))[0] == pytest.approx(5.0)
    assert prof.accel(np.array([1.0]))[0] == pytest.approx(np.pi / 4)   # (Δr/2)·π/T at mid-ramp


def test_profiles_reject_empty_or_zero_length_segments():
    with pytest.raises(ValueError):
        RateProfile([])
    with pytest.raises(ValueError):
        RateProfile([hold(0.0)])


def test_smoothstep_is_clamped_with_flat_ends():
    x = np.array([-1.0, 0.0, 0.5, 1.0, 2.0])
    np.testing.assert_allclose(smoothstep(x), [0.0, 0.0, 0.5, 1.0, 1.0])
