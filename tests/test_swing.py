"""Heading-deviation (swing) fit δψ = A + B sinψ + C cosψ + D sin2ψ + E cos2ψ (Nourmohammadi & Sabet 2022, eqs. 19–21, 31)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from ahrsd.calibration.mag import swing
from ahrsd.core.angles import wrap_180_deg

EIGHT = ("N", "NE", "E", "SE", "S", "SW", "W", "NW")


def _dev(coef, psi_deg):
    p = np.radians(psi_deg)
    a, b, c, d, e = coef
    return a + b * np.sin(p) + c * np.cos(p) + d * np.sin(2 * p) + e * np.cos(2 * p)


@settings(max_examples=50, deadline=None, derandomize=True)
@given(st.lists(st.floats(-10, 10), min_size=5, max_size=5))
def test_fit_recovers_injected_coefficients_exactly(coef):
    psi = np.arange(0, 360, 15.0)
    ref = psi + _dev(coef, psi)
    dev = swing.fit_deviation(psi, ref)
    np.testing.assert_allclose(dev.as_array(), coef, atol=1e-9)
    assert dev.rms_after_deg < 1e-9
    np.testing.assert_allclose(wrap_180_deg(dev.apply(psi) - ref), 0, atol=1e-9)


def test_fit_with_noise_is_within_its_standard_error():
    rng = np.random.default_rng(0)
    coef = (8.135, -0.631, 0.614, 0.350, 3.167)   # the paper's Table 7 in degrees (0.14199 rad = 8.135°, …)
    psi = rng.uniform(0, 360, 400)
    ref = psi + _dev(coef, psi) + rng.normal(0, 0.5, psi.size)
    dev = swing.fit_deviation(psi, ref)
    # σ of each coefficient ≈ 0.5°·√(2/400) ≈ 0.035°
    np.testing.assert_allclose(dev.as_array(), coef, atol=0.15)
    assert dev.rms_after_deg == pytest.approx(0.5, abs=0.06)


def test_paper_table7_radians_applied_as_eq31():
    a, b, c, d, e = 0.14199, -0.01101, 0.01071, 0.00610, 0.05528     # the paper's Table 7 (rad)
    dev = swing.DeviationCoefficients(*np.degrees([a, b, c, d, e]))
    psi = 62.0
    r = math.radians(psi)
    expected = psi + math.degrees(a + b * math.sin(r) + c * math.cos(r) + d * math.sin(2 * r) + e * math.cos(2 * r))
    assert float(dev.apply(psi)) == pytest.approx(expected, abs=1e-9)
    assert math.hypot(dev.d_deg, dev.e_deg) == pytest.approx(3.19, abs=0.01)   # √(D² + E²) of Table 7: the 2ψ term dominates


def test_pub226_eight_point_example_and_least_squares_agree():
    # NGA Pub. 226 ch. V example deviations (east +): A 1.0, B 12.0, C 8.0, D 5.0, E 1.5
    d = dict(N=10.5, NE=20.0, E=11.5, SE=-1.2, S=-5.5, SW=-8.0, W=-12.5, NW=-6.8)
    c = swing.pub226_eight_point(d)
    np.testing.assert_allclose(c.as_array(), [1.0, 12.0, 8.0, 5.0, 1.5], atol=0.15)
    headings = np.arange(8) * 45.0
    ls = swing.fit_deviation(headings, headings + np.array([d[k] for k in EIGHT]))
    # least squares uses all 8 headings for B and C (the formulas only 2): same card within 0.15°
    np.testing.assert_allclose(ls.as_array(), [1.0, 12.0, 8.0, 5.0, 1.5], atol=0.15)
    assert ls.a_deg == pytest.approx(c.a_deg) and ls.d_deg == pytest.approx(c.d_deg) and ls.e_deg == pytest.approx(c.e_deg)


def test_offset_only_and_sanity_value():
    psi = np.arange(0, 360, 10.0)
    off = swing.fit_offset(psi, psi + 7.5)
    assert off.a_deg == pytest.approx(7.5) and off.b_deg == 0.0
    wrap = swing.fit_offset([359.0, 1.0], [1.0, 3.0])       # circular mean across north
    assert wrap.a_deg == pytest.approx(2.0)


def test_refuses_too_few_or_clustered_headings():
    with pytest.raises(swing.SwingFitError, match="at least 8"):
        swing.fit_deviation([0, 90, 180], [1, 91, 181])
    psi = np.linspace(40, 80, 50)
    with pytest.raises(swing.SwingFitError, match="sectors"):
        swing.fit_deviation(psi, psi + 3)
    legs = np.concatenate((np.full(30, 62.0), np.full(30, 243.0))) + np.random.default_rng(0).normal(0, 1, 60)
    with pytest.raises(swing.SwingFitError, match="sectors"):       # an out-and-back: two opposite headings
        swing.fit_deviation(legs, legs + 3)
    psi = np.concatenate((np.linspace(0, 40, 20), np.linspace(90, 130, 20), np.linspace(180, 220, 20),
                          np.linspace(270, 310, 20), np.linspace(135, 170, 20)))
    swing.fit_deviation(psi, psi + 3)                                 # 5 sectors: fine
    with pytest.raises(swing.SwingFitError):
        swing.fit_deviation([1, 2], [1, 2, 3])


def test_heading_span():
    assert swing.heading_span_deg([350, 10]) == pytest.approx(20)
    assert swing.heading_span_deg(np.arange(0, 360, 45)) == pytest.approx(315)


def test_gnss_course_reference_delay_speed_and_straightness():
    t = np.arange(0, 200, 0.2)
    true_heading = np.where(t < 100, 30.0, np.where(t < 120, 30 + (t - 100) * 9, 210.0))
    delay = 2.0
    course = np.interp(t - delay, t, true_heading)          # the receiver reports the course 2 s late
    speed = np.where(t < 50, 0.3, 2.5)                      # slow at first
    ref = swing.gnss_course_reference(t, course, speed, delay_s=delay)
    ok = np.isfinite(ref)
    assert not ok[t < 50].any()                             # too slow
    assert not ok[(t > 101) & (t < 121)].any()              # turning
    assert ok[(t > 60) & (t < 90)].all() and ok[(t > 135) & (t < 190)].all()
    np.testing.assert_allclose(ref[ok], true_heading[ok], atol=1e-9)   # delay compensated
    # on a slow steady turn (0.5°/s, under the straightness limit) the delay matters: 2 s × 0.5°/s = 1°
    slow = 30 + 0.5 * t
    course = np.interp(t - delay, t, slow)
    ref = swing.gnss_course_reference(t, course, np.full(t.size, 2.5), delay_s=delay)
    ok = np.isfinite(ref)
    np.testing.assert_allclose(wrap_180_deg(ref[ok] - slow[ok] % 360), 0, atol=1e-9)
    no_delay = swing.gnss_course_reference(t, course, np.full(t.size, 2.5), delay_s=0.0)
    assert np.nanmedian(wrap_180_deg(slow % 360 - no_delay)) == pytest.approx(1.0, abs=1e-6)


def test_load_swing_table(tmp_path):
    f = tmp_path / "swing.csv"
    f.write_text("# compass swing, 8 headings\nreference_deg,compass_deg\n0,358.5\n45,41\n90,91.5\n")
    ref, mag = swing.load_swing_table(f)
    np.testing.assert_allclose(ref, [0, 45, 90])
    np.testing.assert_allclose(mag, [358.5, 41, 91.5])


@pytest.mark.parametrize("text,match", [
    ("", "empty"),
    ("a,b\n1,2\n", "header"),
    ("reference_deg,compass_deg\n10,abc\n", ":2:"),
    ("reference_deg,compass_deg\n10\n", ":2:"),
    ("reference_deg,compass_deg\n10,inf\n", "out of range"),
    ("reference_deg,compass_deg\n", "no rows"),
])
def test_load_swing_table_errors_name_the_line(tmp_path, text, match):
    f = tmp_path / "bad.csv"
    f.write_text(text)
    with pytest.raises(swing.SwingTableError, match=match):
        swing.load_swing_table(f)


def test_load_swing_table_missing_file(tmp_path):
    with pytest.raises(swing.SwingTableError, match="cannot read"):
        swing.load_swing_table(tmp_path / "nope.csv")


def test_fit_swing_table_full_card_and_offset_only(tmp_path):
    coef = (1.0, 2.0, -1.5, 0.5, 0.8)
    psi = np.arange(0, 360, 45.0)
    f = tmp_path / "card.csv"
    f.write_text("reference_deg,compass_deg\n" + "".join(f"{(p + _dev(coef, p)) % 360:.6f},{p}\n" for p in psi))
    np.testing.assert_allclose(swing.fit_swing_table(f).as_array(), coef, atol=1e-5)
    g = tmp_path / "one.csv"
    g.write_text("known_deg,measured_deg\n90,87.5\n")
    one = swing.fit_swing_table(g)
    assert one.a_deg == pytest.approx(2.5) and one.b_deg == 0.0
