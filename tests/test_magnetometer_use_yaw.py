"""The filter hands magnetometer_use the yaw variance it holds at the check (HeadingSupervision._set_magnetometer_use):
`never_trusted_here` weighs the learned magnetometer's floor plus that variance against the trust limit
(docs/gnss.md "boat39"). The part itself is tested alone in tests/test_magnetometer_use.py; here only that the
filter's own P[yaw, yaw] is what reaches it."""

from __future__ import annotations

import math

from ahrsd.estimator import heading_supervision, ins_core
from ahrsd.estimator.heading_monitor import MonitorDecision
from ahrsd.estimator.ins import Ins
from ahrsd.estimator.magnetometer_use import MagnetometerKernelUse

DEG = math.pi / 180.0


def _recorder(monkeypatch) -> dict:
    """The rule replaced by one that records its keyword arguments (the dict returned) and leaves the magnetometer
    unused."""
    seen = {}

    def record(params, **kw):
        seen.update(kw)
        return MagnetometerKernelUse(0.0, 0.0, None, None)

    monkeypatch.setattr(heading_supervision, "magnetometer_use", record)
    return seen


def _set_use(est: Ins, monitor_use: bool) -> None:
    est._heading._set_magnetometer_use(MonitorDecision(monitor_use, 0.0, 0.0, None, 0.0), math.nan, 0.0, math.nan,
                                       math.nan)


def test_the_filters_yaw_variance_reaches_the_rule(monkeypatch):
    seen = _recorder(monkeypatch)
    est = Ins()
    yaw_var = (1.3 * DEG) ** 2
    est._P[ins_core.E_YAW, ins_core.E_YAW] = yaw_var
    _set_use(est, False)
    assert seen["yaw_var_rad2"] == yaw_var


def test_the_learned_irons_held_offset_reaches_the_rule(monkeypatch):
    # pa96: a learned iron whose offset is held may be fused while it is learned (magnetometer_use)
    seen = _recorder(monkeypatch)
    est = Ins()
    for held in (True, False):
        est._iron.offset_held = held
        _set_use(est, True)
        assert seen["iron"].offset_held is held
