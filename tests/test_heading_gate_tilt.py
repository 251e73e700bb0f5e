"""The heading checks' gate holds the filter's tilt error seen through the dip (gate37): the magnetometer heading is
the azimuth of the field turned into NED with the filter's attitude, so a tilt error about the horizontal axis
along the field reads as tan(dip) times as much heading error. Its variance is compared with the spread of that
azimuth under attitude errors drawn from the same covariance and turned with scipy (not the code's formula); a
good calibration seen through an unconverged tilt at dip 74° (what the back-stepping levelling pass rejected
5.6 s in, session 36) is not rejected; a wrong one at a converged tilt is rejected at the same check as without the
term. Constructed monitor inputs, no filter run."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.estimator.heading_monitor import HeadingMonitor, attitude_heading_variances

D = math.radians
FIELD_NED_UT = np.array([14.4, 1.3, 50.3])     # dip 74°, declination 5° (about 60° N, 25° E)


def _azimuth(field_ned) -> np.ndarray:
    f = np.atleast_2d(field_ned)
    return np.arctan2(f[:, 1], f[:, 0])


def _innovation_rad(dtheta) -> np.ndarray:
    """Magnetometer heading − filter yaw for attitude errors δθ (true − estimate, NED rotation vectors, rad,
    n×3):
    a perfect magnetometer reads the field in the true body frame, C_trueᵀ B; the check turns it into NED with the
    filter's attitude C = R(δθ)ᵀ C_true and takes the heading from the field's azimuth there (heading_supervision
    `_magnetometer_heading`): yaw − (azimuth − declination), so the innovation is −(azimuth − declination)."""
    turned = Rotation.from_rotvec(np.atleast_2d(dtheta)).inv().apply(FIELD_NED_UT)
    d = _azimuth(turned) - _azimuth(FIELD_NED_UT)
    return -((d + math.pi) % (2.0 * math.pi) - math.pi)


def _cov(sig_n_deg, sig_e_deg, sig_d_deg, corr_ne=0.0, corr_nd=0.0, corr_ed=0.0) -> np.ndarray:
    s = np.radians([sig_n_deg, sig_e_deg, sig_d_deg])
    r = np.array([[1.0, corr_ne, corr_nd], [corr_ne, 1.0, corr_ed], [corr_nd, corr_ed, 1.0]])
    return r * np.outer(s, s)


@pytest.mark.parametrize("corr", [(0.0, 0.0, 0.0), (0.3, -0.6, 0.4)])
def test_the_variances_are_the_spread_of_the_magnetometer_heading_under_the_attitude_errors(corr):
    """Attitude errors drawn from P (tilt 1σ 0.8°/0.6°, yaw 0.5°, with and without correlations): the innovation's
    variance matches attitude_heading_variances' first, and with the yaw error left out (what the distance to the
    GNSS yaw sees: the bank levels itself) its second. Broken (no tilt–yaw covariance; the field's east part
    dropped; tan(dip) as cos): fails."""
    p = _cov(0.8, 0.6, 0.5, *corr)
    draws = np.random.default_rng(3).multivariate_normal(np.zeros(3), p, size=100_000)
    innovation_var, tilt_var = attitude_heading_variances(p, FIELD_NED_UT)
    assert innovation_var == pytest.approx(np.var(_innovation_rad(draws)), rel=0.03)
    draws[:, 2] = 0.0
    assert tilt_var == pytest.approx(np.var(_innovation_rad(draws)), rel=0.03)
    assert tilt_var > 5.0 * D(0.6) ** 2       # tan²(74°) ≈ 12: the tilt dominates


def test_no_horizontal_field_no_variances():
    assert all(math.isnan(v) for v in attitude_heading_variances(np.eye(3), [0.0, 0.0, 50.0]))


def _run(monitor, innovation_deg, p_att, n=15, term=True, gsf=(math.nan, math.inf, False), velocity_nis=math.nan):
    """n checks at 5 Hz of a magnetometer heading innovation_deg from the filter's yaw (0), the filter's GNSS
    velocity NIS velocity_nis at each; the index of the check that rejected it (None)."""
    att_var, tilt_var = attitude_heading_variances(p_att, FIELD_NED_UT) if term else (math.nan, math.nan)
    for i in range(n):
        d = monitor.check(0.2 * i, 0.0, float(p_att[2, 2]), D(innovation_deg), D(0.43) ** 2 + D(0.3) ** 2,
                          gsf[0], gsf[1], gsf[2], True, velocity_nis, attitude_innovation_var_rad2=att_var,
                          mag_tilt_var_rad2=tilt_var)
        if not d.mag_use:
            return i
    return None


def test_a_good_magnetometer_seen_through_an_unconverged_tilt_is_not_rejected():
    """Session 36's levelling pass at 60° N: the filter's tilt 1σ 4.3°, its yaw 1σ 2.85°, a calibration stating
    0.43°; the filter's tilt is 3° off about the horizontal axis along the field, so a perfect magnetometer's
    heading is ~10° from the filter's yaw (turned with scipy). The gate without the term (3σ of yaw, calibration
    and noise: 8.8°) rejects it at the third check; with it (the tilt through the dip: 15° 1σ) it is kept.
    Broken (the term left out of the gate): fails."""
    p = _cov(4.3, 4.3, 2.85)
    u = FIELD_NED_UT[:2] / np.hypot(*FIELD_NED_UT[:2])
    innovation = math.degrees(float(_innovation_rad(D(3.0) * np.array([u[0], u[1], 0.0]))[0]))
    assert 9.0 < abs(innovation) < 12.0
    assert _run(HeadingMonitor(D(0.43)), innovation, p, term=False) == 2       # what the gate did before
    assert _run(HeadingMonitor(D(0.43)), innovation, p, velocity_nis=2.0) is None


def test_while_the_velocity_fusion_fails_the_attitude_covariance_is_not_read():
    """The same checks while the filter's GNSS velocity fusion fails (NIS 100 at every fix: a start in a hard turn
    levelled the turn's lean, tens of degrees beyond its σ): its covariance does not cover its attitude, so the gate
    is the one without the term, and the magnetometer is rejected at the third check (the rejection that lets the
    GNSS yaw reset the heading, docs/gnss.md gate37). Broken (the term read whatever the velocity fusion says):
    fails."""
    p = _cov(4.3, 4.3, 2.85)
    u = FIELD_NED_UT[:2] / np.hypot(*FIELD_NED_UT[:2])
    innovation = math.degrees(float(_innovation_rad(D(3.0) * np.array([u[0], u[1], 0.0]))[0]))
    assert _run(HeadingMonitor(D(0.43)), innovation, p, velocity_nis=100.0) == 2


@pytest.mark.parametrize("gsf", [(math.nan, math.inf, False), (0.0, D(1.0) ** 2, True)])
def test_a_wrong_calibration_at_a_converged_tilt_is_rejected_as_fast(gsf):
    """A converged filter (tilt 1σ 0.05°, yaw 0.3°) whose magnetometer heading is 8° off (a wrong calibration or a
    moved iron; with and without a valid GNSS yaw at the filter's): rejected at the third check, as without the
    term. Broken (a term that widens the gate beyond the tilt's share, e.g. tan(dip) times the yaw σ): fails."""
    p = _cov(0.05, 0.05, 0.3)
    assert _run(HeadingMonitor(D(0.43)), 8.0, p, gsf=gsf) == 2
    assert _run(HeadingMonitor(D(0.43)), 8.0, p, gsf=gsf, term=False) == 2
    # the smallest disagreement each gate rejects moves by less than 0.1°
    mon_var = D(0.43) ** 2 + D(0.3) ** 2
    with_term = 3.0 * math.sqrt(attitude_heading_variances(p, FIELD_NED_UT)[0] + mon_var)
    without = 3.0 * math.sqrt(p[2, 2] + mon_var)
    assert math.degrees(with_term - without) < 0.1


def test_against_the_gnss_yaw_the_tilt_share_counts_in_full():
    """The filter's yaw has followed the magnetometer read at its tilt (its yaw error 5.5° correlated 0.98 with
    its tilt error along the field, 2.9°; tilt 1σ 4.3°, yaw 15°), so the innovation is small (−4.6°, 1.5σ) while
    the magnetometer heading is 10° from the true yaw, where a valid GNSS yaw (1σ 1°) is. Its distance from the
    GNSS yaw is the tilt's share alone: within the gate with it, beyond it (3.4°) without, which rejected the
    magnetometer at the third check. Broken (the GNSS-yaw clause without the tilt's share): fails."""
    u = FIELD_NED_UT[:2] / np.hypot(*FIELD_NED_UT[:2])
    basis = np.array([[u[0], -u[1], 0.0], [u[1], u[0], 0.0], [0.0, 0.0, 1.0]])    # along, across, down
    s_t, s_y, rho = D(4.3), D(15.0), 0.98
    p = basis @ np.array([[s_t ** 2, 0.0, rho * s_t * s_y], [0.0, s_t ** 2, 0.0],
                          [rho * s_t * s_y, 0.0, s_y ** 2]]) @ basis.T
    error = basis @ np.array([D(2.9), 0.0, D(5.5)])
    innovation = math.degrees(float(_innovation_rad(error)[0]))
    assert -6.0 < innovation < -3.5
    gsf = (D(5.5), D(1.0) ** 2, True)                   # the true yaw, 5.5° from the filter's
    assert _run(HeadingMonitor(D(0.43)), innovation, p, gsf=gsf) is None
    mon = HeadingMonitor(D(0.43))
    att_var, _ = attitude_heading_variances(p, FIELD_NED_UT)
    for i in range(3):         # the same checks with the GNSS-yaw clause told no tilt share
        d = mon.check(0.2 * i, 0.0, float(p[2, 2]), D(innovation), D(0.43) ** 2 + D(0.3) ** 2, *gsf, True,
                      attitude_innovation_var_rad2=att_var, mag_tilt_var_rad2=0.0)
    assert not d.mag_use


def test_ins_gives_the_gate_its_attitude_covariance_through_the_wmm_field():
    """`ins`'s heading checks hand the monitor the variances of its own attitude covariance at the check, seen
    through the WMM field at its position: at the checks of a calibrated boat's first 8 s at 60° N they match
    the spread of the innovation under attitude errors drawn from that covariance and turned with scipy. Broken
    (the checks hand the monitor nothing): fails."""
    from ahrsd.core.wmm import earth_field
    from ahrsd.estimator import heading_monitor
    from ahrsd.estimator.ins import Ins
    from bench.vehicle_accuracy import estimates_in_arrival_order, simulate_vehicle

    run = simulate_vehicle("boat", 8.0, 1, "60.17,24.94,20,2026-06-15")
    est = Ins(declination_rad=run.declination_rad, mag_calibration_sigma_rad=run.mag_calibration_sigma_rad)
    seen = []
    check = heading_monitor.HeadingMonitor.check

    def spy(self, *args, **kwargs):
        seen.append((args[0], est._P[0:3, 0:3].copy(), args[15], args[16]))    # t, P, the two variances
        return check(self, *args, **kwargs)

    heading_monitor.HeadingMonitor.check = spy
    try:
        for _ in estimates_in_arrival_order(est, run, run.fixes):
            pass
    finally:
        heading_monitor.HeadingMonitor.check = check
    assert len(seen) > 20
    field = earth_field(math.degrees(est._x["lat_rad"]), math.degrees(est._x["lon_rad"]), float(est._x["h_m"])).ned_ut
    rng = np.random.default_rng(5)
    # after the first second: at the first check the tilt's 5° (17° through the dip) is beyond the linear range
    for t, p, att_var, tilt_var in [c for c in seen if c[0] > 1.0][::8]:
        # the spread of the field's azimuth at the filter's attitude under errors drawn from its covariance
        draws = rng.multivariate_normal(np.zeros(3), p, size=40_000)
        turned = Rotation.from_rotvec(draws).inv().apply(field)
        spread = np.var(np.arctan2(turned[:, 1], turned[:, 0]))
        assert att_var == pytest.approx(spread, rel=0.05)
        draws[:, 2] = 0.0
        turned = Rotation.from_rotvec(draws).inv().apply(field)
        assert tilt_var == pytest.approx(np.var(np.arctan2(turned[:, 1], turned[:, 0])), rel=0.05)
