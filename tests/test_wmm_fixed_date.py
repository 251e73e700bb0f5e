"""core.wmm.fixed_date: a lookup without a date uses the fixed date inside it and today's outside it (what makes
tools/estimate_digest.py reproducible across midnight)."""

import datetime as dt

from ahrsd.core import wmm


def test_a_lookup_without_a_date_uses_the_fixed_date_and_today_after_it():
    place = (52.0, 4.0, 0.0)
    far = dt.date(2029, 6, 1)       # 2.5 years of secular variation from today's date: tens of nT
    on_far = wmm.earth_field(*place, date=far)
    today = wmm.earth_field(*place, date=dt.date.today())
    assert abs(on_far.declination_rad - today.declination_rad) > 1e-5
    with wmm.fixed_date(far):
        assert wmm.earth_field(*place) == on_far
        assert wmm.decimal_year() == wmm.decimal_year(far)
    assert wmm.earth_field(*place) == wmm.earth_field(*place, date=dt.date.today())
