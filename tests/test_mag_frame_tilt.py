"""estimator/mag_frame_tilt.py: the heading row's partials on the calibration frame's tilt, and its prior.

The partials are checked against the field azimuth computed directly (scipy's rotations, atan2): the calibrated
magnetometer reads the body field through the frame rotated by ε, the filter levels it with the true attitude,
and the azimuth it finds moves by ∂α/∂ε · ε for a small ε, at any attitude and heading."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.core.angles import STANDARD_GRAVITY_M_S2
from ahrsd.core.sample import ImuSample
from ahrsd.estimator import ins_core as core
from ahrsd.estimator.ins import Ins
from ahrsd.estimator.mag_frame_tilt import accel_bias_share, frame_tilt_partials

FIELD_NED_UT = np.array([22.0, 1.5, 41.0])     # dip 62°, a little declination left in


def _azimuth_rad(v) -> float:
    return math.atan2(v[1], v[0])


def _row_on_attitude(m_ned):
    """The heading row's entries on δθ (N, E, D) for the field levelled in NED (ins_core._mag_heading_row, aided):
    written out here from α = −δθ_D + (Z/H) u·δθ."""
    mn, me, md = m_ned
    mh2 = mn * mn + me * me
    return md * mn / mh2, md * me / mh2, -1.0


@pytest.mark.parametrize("roll_deg, pitch_deg, yaw_deg", [(0, 0, 0), (0, 0, 90), (3, -2, 200), (20, 8, 45),
                                                          (-15, 12, 300)])
def test_the_partials_are_how_the_levelled_field_turns_with_the_frame_tilt(roll_deg, pitch_deg, yaw_deg):
    c_bn = Rotation.from_euler("ZYX", [yaw_deg, pitch_deg, roll_deg], degrees=True)
    m_body = c_bn.inv().apply(FIELD_NED_UT)
    base = _azimuth_rad(FIELD_NED_UT)
    partials = frame_tilt_partials(*_row_on_attitude(FIELD_NED_UT), tuple(c_bn.as_matrix().ravel()))
    for k in range(2):
        eps = np.zeros(3)
        eps[k] = 1e-4
        seen = c_bn.apply(Rotation.from_rotvec(eps).apply(m_body))
        moved = (_azimuth_rad(seen) - base) / 1e-4
        assert partials[k] == pytest.approx(moved, rel=2e-3, abs=2e-4), (k, partials, moved)


def test_a_level_vehicle_sees_the_frame_tilt_once_per_turn_through_the_dip():
    """Level, heading ψ from magnetic north: α = −tan(dip)·(ε_x cos ψ − ε_y sin ψ) (levelling_error.py's
    tan(dip)·(ε_x cos ψ − ε_y sin ψ) with the row's sign: what the calibration's field azimuth gains the estimate
    loses)."""
    field = np.array([20.0, 0.0, 35.0])
    tan_dip = 35.0 / 20.0
    for psi in np.radians([0.0, 30.0, 90.0, 135.0, 250.0]):
        c = Rotation.from_euler("Z", psi).as_matrix()
        px, py = frame_tilt_partials(tan_dip, 0.0, -1.0, tuple(c.ravel()))
        assert px == pytest.approx(-tan_dip * math.cos(psi), abs=1e-12)
        assert py == pytest.approx(tan_dip * math.sin(psi), abs=1e-12)


def _initialised_ins(**params) -> Ins:
    """An ins started on a second of a level, still vehicle with its magnetometer silent (no heading update): its
    covariance as set at initialisation, propagated."""
    ins = Ins(declination_rad=0.0, mag_calibration_sigma_rad=math.radians(0.4), **params)
    nan3 = np.full(3, np.nan)
    for n in range(150):
        ins.update(ImuSample(t_s=n * 0.01, gyro_rad_s=np.zeros(3), accel_m_s2=np.array([0.0, 0.0, -9.81]),
                             mag_ut=nan3))
    return ins


def test_the_prior_shares_the_calibrations_bias_with_the_filter():
    """At start-up the frame tilt's covariance with the filter's accelerometer bias is the levelling's (g σ)²
    (ε_x with the lateral bias, ε_y against the forward one: the frame in which f = b − g e_z reads level is
    turned by (b_y, −b_x)/g), its variance σ², the covariance positive semi-definite; stated 0, the states carry
    nothing; independent of the bias when told so."""
    sigma = math.radians(0.25)
    g = STANDARD_GRAVITY_M_S2
    P = _initialised_ins(mag_calibration_frame_tilt_sigma_rad=sigma).covariance
    ex, ey, bx, by = core.E_MF, core.E_MF + 1, core.E_BA, core.E_BA + 1
    assert P[ex, ex] == pytest.approx(sigma ** 2) and P[ey, ey] == pytest.approx(sigma ** 2)
    assert P[ex, by] == pytest.approx(g * sigma ** 2, rel=1e-6)
    assert P[ey, bx] == pytest.approx(-g * sigma ** 2, rel=1e-6)
    assert P[ex, bx] == P[ey, by] == 0.0
    assert np.min(np.linalg.eigvalsh(P)) > -1e-12
    off = _initialised_ins(mag_calibration_frame_tilt_sigma_rad=0.0).covariance
    assert not np.any(off[ex:ey + 1, :]) and not np.any(off[:, ex:ey + 1])
    alone = _initialised_ins(mag_calibration_frame_tilt_sigma_rad=sigma,
                             mag_frame_tilt_shares_accel_bias=False).covariance
    assert alone[ex, ex] == pytest.approx(sigma ** 2) and alone[ex, by] == 0.0 and alone[ey, bx] == 0.0


def test_a_bias_known_better_than_the_tilt_is_shared_whole():
    """A calibrated accelerometer's bias (σ_b below g σ): the regression takes all of it, never more than σ²."""
    sigma = math.radians(0.25)
    g = STANDARD_GRAVITY_M_S2
    tight = accel_bias_share(sigma, [(0.5 * g * sigma) ** 2] * 3)
    assert tight[0, 1] == pytest.approx(1.0 / g) and tight[1, 0] == pytest.approx(-1.0 / g)
    loose = accel_bias_share(sigma, [(4.0 * g * sigma) ** 2] * 3)
    assert loose[0, 1] == pytest.approx(1.0 / (16.0 * g))


def test_the_calibration_states_its_levelling_tilt_and_replay_tells_ins():
    """`calibrate mag` stores the levelling's body-fixed tilt (the aided levelling's stated tilt, or the
    accelerometer's bias over g) as `frame_tilt_std_deg`; heading_trust reads it back (0: none stated, the frame is
    the body's) and `ahrsd replay --calibration` passes it to ins as the daemon does."""
    import dataclasses

    from ahrsd.calibration.heading_trust import calibration_frame_tilt_sigma_rad
    from ahrsd.calibration.mag.levelling_error import frame_tilt_sigma_deg
    from ahrsd.calibration.models import Calibration
    from ahrsd.cli.replay import _told_calibration_sigma

    assert frame_tilt_sigma_deg({"given_tilt_sigma_deg": 0.22, "given_tilt_heading_std_deg": 0.33}) == 0.22
    bias = 0.05
    assert frame_tilt_sigma_deg({"accel_bias_sigma_m_s2": bias, "residual_correlation_samples": 3.0}) == \
        pytest.approx(math.degrees(bias / STANDARD_GRAVITY_M_S2))
    assert frame_tilt_sigma_deg(None) is None and frame_tilt_sigma_deg({}) is None
    stated = dataclasses.replace(Calibration.identity(), metadata={"mag": {"heading_std_deg": 0.33,
                                                                           "offset_std_deg": 0.15,
                                                                           "frame_tilt_std_deg": 0.22}})
    older = dataclasses.replace(Calibration.identity(), metadata={"mag": {"heading_std_deg": 0.33,
                                                                          "offset_std_deg": 0.15}})
    assert calibration_frame_tilt_sigma_rad(stated) == pytest.approx(math.radians(0.22))
    assert calibration_frame_tilt_sigma_rad(older) == 0.0 and calibration_frame_tilt_sigma_rad(None) == 0.0
    told = _told_calibration_sigma("ins", stated, {})
    assert told["mag_calibration_frame_tilt_sigma_rad"] == pytest.approx(math.radians(0.22))
    assert "mag_calibration_frame_tilt_sigma_rad" not in _told_calibration_sigma("mekf", stated, {})
    ins = Ins(declination_rad=0.0, **told)
    assert ins.params.mag_calibration_frame_tilt_sigma_rad == pytest.approx(math.radians(0.22))
    # the daemon tells it at start and after every calibration change, after the heading error
    from ahrsd.daemon.service import Service

    ins = Ins(declination_rad=0.0)
    Service._tell_calibration(ins, stated)
    assert ins.params.mag_calibration_frame_tilt_sigma_rad == pytest.approx(math.radians(0.22))
    Service._tell_calibration(ins, older)
    assert ins.params.mag_calibration_frame_tilt_sigma_rad == 0.0


def _level_heading_variance_rad2(P, tan_dip: float, psi_rad: float) -> float:
    """The variance of the heading error the calibration's states hold at a level magnetic heading ψ, from the
    covariance `P`: the harmonics' e(ψ) = (1, cos ψ, sin ψ, cos 2ψ, sin 2ψ)·c (mag_harmonics.py) and the frame tilt's
    −tan(dip)(cos ψ, −sin ψ)·ε (the level closed form above), written out here."""
    row = np.zeros(P.shape[0])
    row[core.E_MH:core.E_MH + 5] = [1.0, math.cos(psi_rad), math.sin(psi_rad), math.cos(2.0 * psi_rad),
                                    math.sin(2.0 * psi_rad)]
    row[core.E_MF:core.E_MF + 2] = [-tan_dip * math.cos(psi_rad), tan_dip * math.sin(psi_rad)]
    return float(row @ P @ row)


@pytest.mark.parametrize("tilt_deg, dip_deg", [(0.1, 55.0), (0.22, 55.85), (0.07, 78.0), (0.08, 78.0)])
def test_the_harmonics_leave_the_frame_tilts_heading_share_to_its_states(tilt_deg, dip_deg):
    """A calibration's stated heading error σ holds its frame tilt's tan(dip)·σ_ε in quadrature
    (levelling_error.py); the frame-tilt states carry that tilt, so the harmonics' prior leaves its share out and
    at every level heading the states together hold σ², not σ² + tan²(dip)σ_ε² (frame26's double count). The tilt
    can be more than the harmonics' once-per-turn share (the rest comes out of c2, s2, then c0). A
    calibration that does not state the share (older files) keeps the old prior."""
    sigma = math.radians(0.4)
    tilt = math.radians(tilt_deg)
    tan_dip = math.tan(math.radians(dip_deg))
    share = tan_dip * tilt
    assert share < sigma
    P = _initialised_ins(mag_calibration_frame_tilt_sigma_rad=tilt,
                         mag_calibration_frame_tilt_heading_sigma_rad=share).covariance
    older = _initialised_ins(mag_calibration_frame_tilt_sigma_rad=tilt).covariance
    for psi in np.radians([0.0, 40.0, 90.0, 160.0, 275.0]):
        assert _level_heading_variance_rad2(P, tan_dip, psi) == pytest.approx(sigma ** 2, rel=1e-4)
        assert _level_heading_variance_rad2(older, tan_dip, psi) == pytest.approx(sigma ** 2 + share ** 2, rel=1e-4)
    harmonics = np.diag(P)[core.E_MH:core.E_MH + 5]
    assert np.all(harmonics >= 0.0)
    assert harmonics[1] == pytest.approx(harmonics[2]) and harmonics[3] == pytest.approx(harmonics[4])
    # the tilt is once per turn: out of c1, s1 first (f0 = 0.25, 2 : 1: each 0.5 σ²), then c2, s2 (each 0.25 σ²),
    # the constant c0 (0.25 σ²) last
    if share ** 2 <= 0.5 * sigma ** 2:
        assert harmonics[3] == pytest.approx(0.25 * sigma ** 2, rel=1e-4)
    else:
        assert harmonics[1] == pytest.approx(0.0, abs=1e-9)   # the walk of 1.5 s: 1.5e-10
    if share ** 2 <= 0.75 * sigma ** 2:
        assert harmonics[0] == pytest.approx(0.25 * sigma ** 2, rel=1e-4)
    else:
        assert harmonics[3] == pytest.approx(0.0, abs=1e-9)   # the walk of 1.5 s: 1.5e-10


def test_the_calibration_states_its_tilts_heading_share_and_the_daemon_and_replay_tell_ins():
    """`calibrate mag` stores the tilt's share of its heading error (the levelling's `given_tilt_heading_std_deg`,
    or the accelerometer's `accel_bias_heading_std_deg`) as `frame_tilt_heading_std_deg`; heading_trust reads it
    back (0: not stated); replay passes it and the daemon tells it after the heading error, the harmonics then
    starting from the prior without it (the same covariance as ins built with it)."""
    import dataclasses

    from ahrsd.calibration.heading_trust import calibration_frame_tilt_heading_sigma_rad
    from ahrsd.calibration.mag.levelling_error import frame_tilt_heading_std_deg
    from ahrsd.calibration.models import Calibration
    from ahrsd.cli.replay import _told_calibration_sigma
    from ahrsd.daemon.service import Service

    assert frame_tilt_heading_std_deg({"given_tilt_sigma_deg": 0.22, "given_tilt_heading_std_deg": 0.33}) == 0.33
    assert frame_tilt_heading_std_deg({"accel_bias_sigma_m_s2": 0.05, "accel_bias_heading_std_deg": 0.41,
                                       "residual_correlation_samples": 3.0}) == 0.41
    assert frame_tilt_heading_std_deg(None) is None and frame_tilt_heading_std_deg({}) is None
    mag = {"heading_std_deg": 0.33, "offset_std_deg": 0.15, "frame_tilt_std_deg": 0.22}
    stated = dataclasses.replace(Calibration.identity(), metadata={"mag": {**mag, "frame_tilt_heading_std_deg": 0.2}})
    older = dataclasses.replace(Calibration.identity(), metadata={"mag": mag})
    assert calibration_frame_tilt_heading_sigma_rad(stated) == pytest.approx(math.radians(0.2))
    assert calibration_frame_tilt_heading_sigma_rad(older) == 0.0
    assert calibration_frame_tilt_heading_sigma_rad(None) == 0.0
    told = _told_calibration_sigma("ins", stated, {})
    assert told["mag_calibration_frame_tilt_heading_sigma_rad"] == pytest.approx(math.radians(0.2))
    assert _told_calibration_sigma("ins", older, {})["mag_calibration_frame_tilt_heading_sigma_rad"] == 0.0
    assert "mag_calibration_frame_tilt_heading_sigma_rad" not in _told_calibration_sigma("mekf", stated, {})
    built = Ins(declination_rad=0.0, **told).covariance
    ins = Ins(declination_rad=0.0)
    Service._tell_calibration(ins, stated)
    assert ins.params.mag_calibration_frame_tilt_heading_sigma_rad == pytest.approx(math.radians(0.2))
    block = slice(core.E_MH, core.E_MF + 2)
    np.testing.assert_allclose(ins.covariance[block, block], built[block, block], rtol=1e-12, atol=0.0)
    sigma = math.radians(math.hypot(0.33, 0.15))
    once = 0.75 * (2.0 / 3.0) * sigma ** 2     # c1's share of an older file's prior (f0 = 0.25, 2 : 1)
    assert ins.covariance[core.E_MH + 1, core.E_MH + 1] == pytest.approx(once - math.radians(0.2) ** 2, rel=1e-9)
    Service._tell_calibration(ins, older)
    assert ins.covariance[core.E_MH + 1, core.E_MH + 1] == pytest.approx(once, rel=1e-9)
