"""estimator/protocol_check.py: the daemon's answer to "is this estimator aided / heading-checked / circle-checked"
is isinstance's for every object asked about, and isinstance runs once per object, not at every question."""

from __future__ import annotations

import typing

from ahrsd.estimator.base import GnssAidedEstimator, HeadingCheckedEstimator
from ahrsd.estimator.protocol_check import ProtocolCheck


def test_the_answer_follows_the_object_asked_about():
    """Two estimators of different kinds asked about in turn (the pipeline given another one): each answer is
    isinstance's own. Broken (the first answer kept): the mekf is called aided."""
    from ahrsd.estimator import make_estimator

    ins, mekf = make_estimator("ins"), make_estimator("mekf")
    aided, checked = ProtocolCheck(GnssAidedEstimator), ProtocolCheck(HeadingCheckedEstimator)
    for est in (ins, ins, mekf, ins, mekf, mekf, None, ins):
        assert aided(est) is isinstance(est, GnssAidedEstimator)
        assert checked(est) is isinstance(est, HeadingCheckedEstimator)
    assert aided(ins) and not aided(mekf) and not aided(None)


def test_isinstance_runs_once_per_object(monkeypatch):
    """Counted by the protocols' metaclass: 100 questions about one object, then another, then the first again,
    are three checks. Broken (worked out at every question): 201."""
    meta = type(GnssAidedEstimator)
    assert meta is typing._ProtocolMeta
    calls = []
    original = meta.__instancecheck__
    monkeypatch.setattr(meta, "__instancecheck__", lambda cls, obj: calls.append(obj) or original(cls, obj))

    class Aided:
        name, gnss_counters, lever_arm_m = "aided", None, (0.0, 0.0, 0.0)

        def update_gnss(self, fix):
            return 0

        def lever_arm_fit(self):
            return None

        def lever_arm_adopted_m(self):
            return None

    a, b = Aided(), object()
    aided = ProtocolCheck(GnssAidedEstimator)
    answers = [aided(a) for _ in range(100)] + [aided(b) for _ in range(100)] + [aided(a)]
    assert answers == [True] * 100 + [False] * 100 + [True]
    assert len(calls) == 3
