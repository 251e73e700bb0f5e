"""The edge validator: every rejection reason counted and logged (rate-limited); it never raises."""

import dataclasses
import logging
import math

import numpy as np
import pytest

from ahrsd.core.gnss import GnssFixType, make_fix
from ahrsd.drivers.gnss.validation import GnssFixValidator, GnssRejection


class FakeClock:
    t = 0.0

    def __call__(self):
        return self.t


def _fix(t=1.0, **kw):
    base = dict(h_acc_m=1.5, v_acc_m=3.0, s_acc_m_s=0.2, fix_type=GnssFixType.FIX_3D, num_sats=10)
    base.update(kw)
    return make_fix(t, 47.0, 8.0, 500.0, [1.0, 2.0, 0.1], **base)


def _with(fix, **kw):
    return dataclasses.replace(fix, **kw)


def test_good_fixes_are_accepted():
    v = GnssFixValidator()
    assert v.check(_fix(1.0)) is None and v.check(_fix(1.2)) is None
    # NaN down velocity and NaN accuracies mean "not reported" (NMEA, GPS_RAW_INT): accepted
    nmea_like = make_fix(1.4, 47.0, 8.0, 500.0, [1.0, 2.0, math.nan])
    assert v.check(nmea_like) is None
    # a 2D fix need not have an altitude
    assert v.check(make_fix(1.6, 47.0, 8.0, math.nan, [1.0, 2.0, math.nan], fix_type=GnssFixType.FIX_2D)) is None
    assert v.counters["accepted"] == 4 and v.rejected == 0


@pytest.mark.parametrize("bad, reason", [
    (lambda f: _with(f, t_s=math.nan), GnssRejection.NONFINITE_TIME),
    (lambda f: _with(f, t_s=0.5), GnssRejection.TIME_BACKWARDS),
    (lambda f: _with(f, t_s=1.0), GnssRejection.TIME_REPEATED),
    (lambda f: _with(f, t_s=2.0, extra={"receiver_time_s": 100.0}), GnssRejection.TIME_REPEATED),
    (lambda f: _with(f, t_s=2.0, fix_type=GnssFixType.NO_FIX), GnssRejection.NO_FIX),
    (lambda f: _with(f, t_s=2.0, fix_type=GnssFixType.NO_GPS), GnssRejection.NO_FIX),
    (lambda f: _with(f, t_s=2.0, lat_deg=math.nan), GnssRejection.NONFINITE_FIELD),
    (lambda f: _with(f, t_s=2.0, alt_m=math.inf), GnssRejection.NONFINITE_FIELD),
    (lambda f: _with(f, t_s=2.0, vel_ned_m_s=np.array([math.nan, 0.0, 0.0])), GnssRejection.NONFINITE_FIELD),
    (lambda f: _with(f, t_s=2.0, vel_ned_m_s=np.array([0.0, 0.0, -math.inf])), GnssRejection.NONFINITE_FIELD),
    (lambda f: _with(f, t_s=2.0, h_acc_m=math.inf), GnssRejection.NONFINITE_FIELD),
    (lambda f: _with(f, t_s=2.0, lat_deg=90.5), GnssRejection.OUT_OF_RANGE),
    (lambda f: _with(f, t_s=2.0, lon_deg=-180.01), GnssRejection.OUT_OF_RANGE),
    (lambda f: _with(f, t_s=2.0, alt_m=-1500.0), GnssRejection.OUT_OF_RANGE),
    (lambda f: _with(f, t_s=2.0, alt_m=70000.0), GnssRejection.OUT_OF_RANGE),
    (lambda f: _with(f, t_s=2.0, vel_ned_m_s=np.array([500.0, 400.0, 0.0])), GnssRejection.OUT_OF_RANGE),
    (lambda f: _with(f, t_s=2.0, vel_ned_m_s=np.array([0.0, 0.0, 350.0])), GnssRejection.OUT_OF_RANGE),
    (lambda f: _with(f, t_s=2.0, h_acc_m=0.0), GnssRejection.BAD_ACCURACY),
    (lambda f: _with(f, t_s=2.0, v_acc_m=-1.0), GnssRejection.BAD_ACCURACY),
    (lambda f: _with(f, t_s=2.0, s_acc_m_s=0.0), GnssRejection.BAD_ACCURACY),
    (lambda f: None, GnssRejection.MALFORMED),
    (lambda f: "$GPGGA", GnssRejection.MALFORMED),
    (lambda f: _with(f, t_s=2.0, vel_ned_m_s=np.zeros(2)), GnssRejection.MALFORMED),
    (lambda f: _with(f, t_s="soon"), GnssRejection.MALFORMED),
])
def test_each_rejection(bad, reason):
    v = GnssFixValidator()
    first = _with(_fix(1.0), extra={"receiver_time_s": 100.0})
    assert v.check(first) is None
    assert v.check(bad(_fix(1.0))) is reason
    assert v.counters[reason.value] == 1 and v.rejected == 1 and v.last_rejection is reason and v.last_detail
    assert v.check(_fix(3.0)) is None          # a bad fix does not move the time reference


def test_just_inside_the_limits_is_accepted():
    v = GnssFixValidator()
    f = _fix(1.0)
    assert v.check(_with(f, lat_deg=-90.0, lon_deg=180.0, alt_m=-999.0)) is None
    assert v.check(_with(f, t_s=2.0, vel_ned_m_s=np.array([599.0, 0.0, 299.0]))) is None


def test_rejections_are_logged_rate_limited(caplog):
    clock = FakeClock()
    v = GnssFixValidator(clock=clock)
    caplog.set_level(logging.WARNING, logger="ahrsd.drivers.gnss.validation")
    for k in range(20):
        clock.t = 0.1 * k
        v.check(_fix(1.0 + k, fix_type=GnssFixType.NO_FIX))
    assert v.counters["no_fix"] == 20
    assert len(caplog.records) == 1 and "no_fix" in caplog.text
    clock.t = 12.0
    v.check(_fix(30.0, fix_type=GnssFixType.NO_FIX))
    v.check(_with(_fix(31.0), lat_deg=math.nan))            # another reason has its own budget
    assert len(caplog.records) == 3
    assert "+19 more" in caplog.records[1].getMessage()
