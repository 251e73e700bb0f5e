"""Whether an estimator implements one of estimator/base.py's runtime-checkable protocols, worked out once per
estimator object instead of at every question.

`isinstance(obj, P)` against a `typing.runtime_checkable` Protocol collects P's members again and looks each up on
`obj` at every call (Python 3.11's `_ProtocolMeta.__instancecheck__`; 3.12 caches the member list). The daemon
asks it of the same estimator at every 10 Hz housekeeping tick and every GNSS fix; the answer changes only when the
pipeline is given another estimator object, and the estimators' members are their classes' methods and the
attributes their constructors set."""

from __future__ import annotations

_NOTHING = object()


class ProtocolCheck:
    """`check(obj)`: `isinstance(obj, protocol)`, remembered for the last object asked about (held: its identity
    cannot be taken by another object meanwhile)."""

    __slots__ = ("protocol", "_last", "_answer")

    def __init__(self, protocol: type):
        self.protocol = protocol
        self._last = _NOTHING
        self._answer = False

    def __call__(self, obj) -> bool:
        if obj is not self._last:
            self._last, self._answer = obj, isinstance(obj, self.protocol)
        return self._answer
