"""The ins mechanisation against the local-navigation-frame equations (Groves 2nd ed. §5.4) and worked values,
and the
filter's strapdown integration against the simulator's analytic trajectories (static on a rotating Earth,
a coordinated turn)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ahrsd.core.gnss import make_fix
from ahrsd.estimator import ins_mechanisation as mech
from ahrsd.estimator.ins import Ins
from ahrsd.simulation import DEFAULT_SITE

from ins_truth import attitude_error_ned, position_error_ned, run_ins, simulated_run
from support.gravity_worked_values import GRAVITY_WORKED_VALUES   # g(0, L) and g(1000 m, L)

R0 = 6_378_137.0        # spherical Earth radius (WGS-84 a)
OMEGA_IE = 7.292e-5     # Earth rate, rounded, rad/s

@pytest.mark.parametrize("lat_deg, g0, g1000", GRAVITY_WORKED_VALUES)
def test_gravity_matches_the_worked_values(lat_deg, g0, g1000):
    assert mech.normal_gravity_m_s2(math.radians(lat_deg), 0.0) == pytest.approx(g0, abs=1e-6)
    assert mech.normal_gravity_m_s2(math.radians(lat_deg), 1000.0) == pytest.approx(g1000, abs=1e-6)


def test_earth_rate_is_15_04_deg_per_hour_with_the_worked_components():
    lat = math.radians(35.7)
    w = np.array(mech.earth_rate_ned(lat))
    assert math.degrees(np.linalg.norm(w)) * 3600.0 == pytest.approx(15.04, abs=0.005)
    np.testing.assert_allclose(w, [5.92e-5, 0.0, -4.26e-5], atol=0.006e-5)     # worked: 7.292e-5·(cos, −sin) 35.7°
    # at the poles it is all vertical, at the equator all north
    np.testing.assert_allclose(mech.earth_rate_ned(math.pi / 2), [0.0, 0.0, -OMEGA_IE], atol=1e-15)
    np.testing.assert_allclose(mech.earth_rate_ned(0.0), [OMEGA_IE, 0.0, 0.0], atol=1e-15)


def test_wgs84_radii_at_equator_and_pole():
    a, e2 = 6378137.0, 6.69437999014e-3
    r_n, r_e = mech.radii_of_curvature_m(0.0)
    assert r_n == pytest.approx(a * (1 - e2), abs=1e-3)        # 6 335 439.3 m
    assert r_e == pytest.approx(a, abs=1e-3)
    r_n, r_e = mech.radii_of_curvature_m(math.pi / 2)
    assert r_n == pytest.approx(a / math.sqrt(1 - e2), abs=1e-3) and r_e == pytest.approx(r_n, abs=1e-3)


_lat = st.floats(-80.0, 80.0).map(math.radians)
_h = st.floats(-100.0, 10000.0)
_v = st.floats(-300.0, 300.0)
_f = st.floats(-40.0, 40.0)


@settings(derandomize=True, max_examples=100, deadline=None)
@given(lat=_lat, h=_h, vn=_v, ve=_v, vd=_v)
def test_transport_rate_and_position_rates_are_eqs_16_and_17_on_the_sphere(lat, h, vn, ve, vd):
    r = R0 + h
    np.testing.assert_allclose(mech.transport_rate_ned(lat, h, vn, ve, R0, R0),
                               [ve / r, -vn / r, -ve * math.tan(lat) / r], rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(mech.position_rates(lat, h, vn, ve, vd, R0, R0),
                               [vn / r, ve / (r * math.cos(lat)), -vd], rtol=1e-12, atol=1e-15)


@settings(derandomize=True, max_examples=200, deadline=None)
@given(lat=_lat, h=_h, vn=_v, ve=_v, vd=_v, fn=_f, fe=_f, fd=_f)
def test_velocity_rate_eq_14_equals_the_expanded_eq_22(lat, h, vn, ve, vd, fn, fe, fd):
    """Eq. 14 (the cross-product form the code uses) against eq. 22 written out component by component."""
    r = R0 + h
    g = 9.780327 * (1 + 0.0053024 * math.sin(lat) ** 2 - 0.0000058 * math.sin(2 * lat) ** 2) * (R0 / r) ** 2
    w, sl, cl, tl = OMEGA_IE, math.sin(lat), math.cos(lat), math.tan(lat)
    expected = [
        fn - 2 * w * ve * sl + (vn * vd - ve * ve * tl) / r,
        fe + 2 * w * (vn * sl + vd * cl) + ve * (vd + vn * tl) / r,
        fd - 2 * w * ve * cl - (ve * ve + vn * vn) / r + g,
    ]
    got = mech.velocity_rate_ned(fn, fe, fd, vn, ve, vd, lat, h, R0, R0, True)
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-9)
    # a non-rotating Earth: specific force plus gravity only
    np.testing.assert_allclose(mech.velocity_rate_ned(fn, fe, fd, vn, ve, vd, lat, h, R0, R0, False),
                               [fn, fe, fd + g], rtol=1e-12, atol=1e-12)


# ------------------------------------------------------------------------------ the filter's strapdown
def _dead_reckon(scenario, seconds, rate_hz, earth_rotation=True):
    """The ins on ideal sensors, velocity and position set from one exact fix at the first sample, then
    no aiding at all (no magnetometer, no levelling, no further fix): pure mechanisation."""
    run = simulated_run(scenario, seconds, rate_hz=rate_hz, errors="ideal", earth_rate=True)
    tr = run.truth
    ins = Ins(mag_enabled=False, dead_reckon_s=1e9, nav_drop_s=1e9, earth_rotation=earth_rotation,
              init_sigma_tilt_rad=1e-6, init_sigma_yaw_rad=1e-6)
    from ahrsd.core.sample import make_sample

    # attitude from the truth (the Wahba start is the levelling's business, not the mechanisation's)
    ins.update(make_sample(tr.t_s[0], run.gyro[0], run.accel[0], run.mag[0]))
    ins._x["q"] = tr.q_wxyz[0]
    fix = make_fix(tr.t_s[0], math.degrees(tr.lat_rad[0]), math.degrees(tr.lon_rad[0]), tr.h_m[0],
                   tr.vel_ned_m_s[0], h_acc_m=0.01, v_acc_m=0.01, s_acc_m_s=0.001)
    ins.update_gnss(fix)
    sub = type(run)(run.block, run.gyro[1:], run.accel[1:], run.mag[1:],
                    type(tr)(tr.t_s[1:], tr.q_wxyz[1:], tr.vel_ned_m_s[1:], tr.lat_rad[1:], tr.lon_rad[1:],
                             tr.h_m[1:]))
    res = run_ins(ins, sub, [])
    att = np.linalg.norm(attitude_error_ned(res.q_true, sub.truth.q_wxyz), axis=1)
    vel = np.linalg.norm(res.vel - sub.truth.vel_ned_m_s, axis=1)
    pos = np.linalg.norm(position_error_ned(res, sub.truth), axis=1)
    return att, vel, pos


def test_stationary_ins_sees_the_earth_rate_and_stays_put_for_60_s():
    run = simulated_run("static", 1.0, rate_hz=50.0, errors="ideal", earth_rate=True)
    assert math.degrees(np.linalg.norm(run.gyro[0])) * 3600 == pytest.approx(15.04, abs=0.01)
    att, vel, pos = _dead_reckon("static", 60.0, 50.0)
    assert att.max() < math.radians(0.001), math.degrees(att.max())
    assert vel.max() < 0.002 and pos.max() < 0.05, (vel.max(), pos.max())


def test_ignoring_the_earth_rate_on_a_rotating_earth_drifts():
    """The same stationary run without the Earth-rate terms tilts by 15 °/h · cos L (0.2° in 60 s) and the
    velocity follows the tilt: the test above would see it."""
    att, vel, pos = _dead_reckon("static", 60.0, 50.0, earth_rotation=False)
    assert att.max() > math.radians(0.15) and vel.max() > 0.3


def test_coordinated_turn_integrates_back_into_its_trajectory():
    """60 s of a 25 m/s fixed-wing in 30° banked turns (the simulator's analytic truth, rotating Earth), dead
    reckoned from the first sample: errors are integration error only."""
    att, vel, pos = _dead_reckon("coordinated-turn", 60.0, 200.0)
    assert att.max() < 2e-5 and vel.max() < 0.02 and pos.max() < 0.5, (att.max(), vel.max(), pos.max())


@pytest.mark.parametrize("earth_model", ["wgs84", "sphere"])
def test_the_earth_model_setting_reaches_the_kernels_radii(earth_model):
    """`Ins(earth_model=…)` picks the radii the kernel integrates latitude and longitude with. (The position
    tests cannot tell: with fixes every 0.2 s the position updates absorb the 0.3 % north scale of the wrong
    model within their bounds.) Truth: the WGS-84 radii from the ellipsoid's defining constants (Groves 2nd ed.
    eqs. 2.105–2.106), or the sphere of the equatorial radius."""
    from ahrsd.estimator import ins_core

    a_m, f = 6378137.0, 1.0 / 298.257223563
    e2 = f * (2.0 - f)
    lat = math.radians(36.0)
    w = 1.0 - e2 * math.sin(lat) ** 2
    expected = (a_m, a_m) if earth_model == "sphere" else (a_m * (1.0 - e2) / w ** 1.5, a_m / math.sqrt(w))
    r_n, r_e = ins_core._radii(Ins(earth_model=earth_model)._par, lat)
    assert (r_n, r_e) == pytest.approx(expected, rel=1e-9)
