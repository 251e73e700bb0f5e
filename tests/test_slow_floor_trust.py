"""The heading checks judge a learned magnetometer's trust on the floor over the monitor's re-entry window
(estimator/slow_floor.py, docs/gnss.md "(pa96)"): the end of the iron learning and the heading state
(`_magnetometer_trust_var`), the re-entry and tilt trust at this attitude (the monitor's mag_bias_var and the next
check's slow variance) and `never_trusted_here`; the kernel still fuses the full floor as noise.

Truth is independent of the code under test: the floor is 1 µT over the WMM horizontal field the test looks up, and
the share is the variance of the mean of an error correlated over 5 s over 20 s, its
autocorrelation integrated numerically by scipy."""

from __future__ import annotations

import inspect
import math

import numpy as np
import pytest
from scipy.integrate import quad

from ahrsd.core.wmm import earth_field
from ahrsd.estimator.heading_monitor import HeadingMonitor, MonitorDecision
from ahrsd.estimator.ins import Ins

FIELD_NED_UT = np.asarray(earth_field(-53.16, -70.91, 0.0).ned_ut, dtype=float)    # Punta Arenas, today's WMM
H2_UT2 = float(FIELD_NED_UT[0] ** 2 + FIELD_NED_UT[1] ** 2)
# the variance of the mean over T = 20 s of a unit error correlated over τ = 5 s: (2/T²)∫₀ᵀ (T − u) e^(−u/τ) du
SHARE = 2.0 * quad(lambda u: (20.0 - u) * math.exp(-u / 5.0), 0.0, 20.0)[0] / 20.0 ** 2
FULL_FLOOR = 1.0 / H2_UT2                   # (1 µT / H)², rad²
SLOW_FLOOR = SHARE * FULL_FLOOR


def _learned_at_punta_arenas() -> Ins:
    """An uncalibrated filter at Punta Arenas with a learned iron of zero and a small covariance (restored)."""
    est = Ins()
    est._learned_iron.restore(np.zeros(3), np.eye(3) * 0.01, np.eye(3), np.eye(9) * 1e-6)
    est._x["lat_rad"], est._x["lon_rad"], est._x["h_m"] = math.radians(-53.16), math.radians(-70.91), 0.0
    assert est._heading.earth_field_ned() == pytest.approx(FIELD_NED_UT)
    return est


def test_the_end_of_the_learning_counts_the_floor_over_the_window():
    est = _learned_at_punta_arenas()
    iron = est._iron.level_heading_variance(FIELD_NED_UT)
    assert est._heading._magnetometer_trust_var(1.0, 0.0, FIELD_NED_UT) == pytest.approx(SLOW_FLOOR + iron, rel=1e-6)


def test_the_magnetometer_heading_states_the_part_the_window_averages_away():
    est = _learned_at_punta_arenas()
    _, var, noise, averaged = est._heading._magnetometer_heading(np.eye(3), 0.0, FIELD_NED_UT)
    assert averaged == pytest.approx(FULL_FLOOR - SLOW_FLOOR, rel=1e-6)
    # what the kernel fuses keeps the whole floor
    assert var - noise == pytest.approx(FULL_FLOOR + est._iron.heading_variance(np.eye(3), FIELD_NED_UT), rel=1e-6)


def test_the_monitor_and_the_next_check_see_the_floor_over_the_window(monkeypatch):
    est = _learned_at_punta_arenas()
    est._x["mag_last_ut"] = FIELD_NED_UT     # level, heading north, no iron: the field as it is
    seen = {}
    names = list(inspect.signature(HeadingMonitor.check).parameters)[1:]

    def record(*args, **kw):
        seen.update(dict(zip(names, args)), **kw)
        return MonitorDecision(True, seen["mag_var_rad2"], 0.0, None, 0.0)

    monkeypatch.setattr(est._heading.monitor, "check", record)
    est._heading.check(1.0)
    iron_here = est._iron.heading_variance(np.eye(3), FIELD_NED_UT)
    assert seen["mag_bias_var_rad2"] == pytest.approx(SLOW_FLOOR + iron_here, rel=1e-4)
    assert seen["iron_trust_var_rad2"] == pytest.approx(
        SLOW_FLOOR + est._iron.level_heading_variance(FIELD_NED_UT), rel=1e-6)
    assert est._heading._mag_var == pytest.approx(seen["mag_bias_var_rad2"])   # the next check's trust
    assert est._heading._learned_floor_var_here() == pytest.approx(SLOW_FLOOR, rel=1e-6)
