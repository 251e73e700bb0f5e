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


@pytest.mark.parametrize("blend", ["cosine", "quintic"])
@settings(derandomize=True, max_examples=60, deadline=None)
@given(segs=chained_segments(), angle0=st.floats(-10, 10))
def test_angle_derivative_is_the_rate_and_both_are_continuous(blend, segs, angle0):
    prof = RateProfile(segs, angle0=angle0, blend=blend)
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
    # accel is the derivative of the rate (away from segment ends, where the cosine blend's accel has kinks)
    numeric_accel = (prof.rate(t + h) - prof.rate(t - h)) / (2 * h)
    ends = np.concatenate([[0.0], np.cumsum([s.duration_s for s in segs])])
    ends = (ends[None, :] + prof.period_s * np.arange(3)[:, None]).ravel()
    away = np.min(np.abs(t[:, None] - ends[None, :]), axis=1) > 10 * h
    np.testing.assert_allclose(numeric_accel[away], prof.accel(t)[away], rtol=1e-4, atol=1e-4)


def test_quintic_blend_has_a_continuous_derivative_where_the_cosine_kinks():
    """The quintic blend's second derivative vanishes at segment ends (C²); the raised cosine's does not."""
    segs = [ramp(4.0, 0.0, 2.0), hold(3.0, 2.0), ramp(4.0, 2.0, 0.0)]
    h = 1e-4
    for blend, jumps in (("quintic", False), ("cosine", True)):
        prof = RateProfile(segs, blend=blend)
        t = np.array([4.0, 7.0])
        second = lambda x: (prof.accel(x + h) - prof.accel(x - h)) / (2 * h)   # noqa: E731
        d2_before, d2_after = second(t - 10 * h), second(t + 10 * h)
        assert (np.max(np.abs(d2_after - d2_before)) > 0.1) == jumps, blend
    with pytest.raises(ValueError, match="blend"):
        RateProfile(segs, blend="linear")


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
