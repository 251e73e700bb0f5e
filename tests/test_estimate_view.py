"""An estimator's step view (estimator/estimate_view.py) has every field of the AttitudeEstimate as a declared
member, not forwarded on demand: a field added to AttitudeEstimate and not to the view fails here, and a name
the estimate does not have is an AttributeError, not a read of the snapshot."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ahrsd.core.estimate import (AttitudeEstimate, EstimateFlags, HeadingIntegrity, HeadingState, NavState)
from ahrsd.estimator.estimate_view import BuiltEstimateView, EstimateView

FIELDS = tuple(f.name for f in dataclasses.fields(AttitudeEstimate))


def _estimate(t_s: float, bits: int, valid: bool) -> AttitudeEstimate:
    """A distinct value in every field (so a field read from the wrong place shows)."""
    return AttitudeEstimate(
        t_s, np.array([0.5, 0.5, 0.5, 0.5]), 0.1, 0.2, 0.3, 0.4, 0.5, np.array([1.0, 2.0, 3.0]),
        np.array([4.0, 5.0, 6.0]), np.array([7.0, 8.0, 9.0]), EstimateFlags(bits),
        NavState(np.array([1.5, 2.5, 3.5]), 52.0, 4.0, 10.0, np.ones(3), 2 * np.ones(3), np.zeros(3)),
        HeadingState.GNSS_ONLY,
        HeadingIntegrity(0.6, 0.07, True, 0.01, np.array([0.1, 0.2, 0.3]), np.array([0.4, 0.5, 0.6])))


def test_every_field_of_the_estimate_is_a_declared_member_of_the_view():
    declared = set(dir(EstimateView)) | set(EstimateView.__annotations__)   # t_s, valid, flags: each view's own
    assert set(FIELDS) <= declared, f"not declared on EstimateView: {sorted(set(FIELDS) - declared)}"
    assert "__getattr__" not in vars(EstimateView)


def test_the_built_view_reads_every_field_of_the_estimate_it_built_once_per_step():
    built = []

    def build(t_s, bits, valid):
        built.append(t_s)
        return _estimate(t_s, bits, valid)

    view = BuiltEstimateView(build)
    view.set(12.5, int(EstimateFlags.NONE), True)
    want = _estimate(12.5, 0, True)
    for name in FIELDS:
        if name == "flags":
            continue                      # the view's own, from the bits (tested below)
        got, expected = getattr(view, name), getattr(want, name)
        if isinstance(expected, (np.ndarray, float)):
            np.testing.assert_array_equal(got, expected, err_msg=name)
        else:
            assert repr(got) == repr(expected), name      # the dataclasses hold arrays: compared as text
    assert built == [12.5]                # one build for all the reads of a step
    view.set(12.6, int(EstimateFlags.NONE), False)
    assert view.flags & EstimateFlags.INITIALISING and view.t_s == 12.6 and view.heading_state == HeadingState.GNSS_ONLY
    assert built == [12.5, 12.6]


def test_a_name_the_estimate_does_not_have_is_an_attribute_error():
    view = BuiltEstimateView(_estimate)
    view.set(1.0, 0, True)
    with pytest.raises(AttributeError):
        view.no_such_field   # noqa: B018
    with pytest.raises(AttributeError):
        view._no_such_private   # noqa: B018
