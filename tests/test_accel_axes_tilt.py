"""ins's tilt is the accelerometer axes' tilt (estimator/accel_axes_tilt.py): the published roll and pitch σ carry
the accelerometer's misalignment as a consider term, the estimate itself unchanged. The partials are checked
against the levelling of a misaligned accelerometer computed here (scipy's rotation, finite differences) and
against the worked heel figures; ins's published σ against the filter's σ plus the hand-computed term."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.core.sample import SampleFlags, make_sample
from ahrsd.estimator.accel_axes_tilt import accel_axes_tilt_variance_in_force_rad2
from ahrsd.estimator.ins import Ins
from ahrsd.estimator.mekf import Mekf

G = 9.80665
SIGMA_M_RAD = math.radians(0.1)          # InsParams.accel_axes_tilt_sigma_rad's default


def _levelled(f):
    """Roll and pitch that put gravity's specific force along f (the accelerometer's own levelling)."""
    return math.atan2(-f[1], -f[2]), math.atan2(f[0], math.hypot(f[1], f[2]))


def _variance_by_element(roll_pitch_of_measured, f, sigma, h=1e-7):
    """Σ over the off-diagonal elements m_jk of the misalignment of ((∂angle/∂m_jk) σ)², roll and pitch, with the
    angles the function gives for the force measured as (I + M) f, differenced at m_jk = h."""
    r0, p0 = roll_pitch_of_measured(f)
    vr = vp = 0.0
    for j in range(3):
        for k in range(3):
            if j == k:
                continue
            m = np.zeros((3, 3))
            m[j, k] = h
            r1, p1 = roll_pitch_of_measured((np.eye(3) + m) @ f)
            vr += ((r1 - r0) / h * sigma) ** 2
            vp += ((p1 - p0) / h * sigma) ** 2
    return vr, vp


def _at_rest_variance(roll, pitch, sigma):
    """The term at this attitude (any heading) and gravity's specific force alone: a vehicle at rest."""
    c_bn = Rotation.from_euler("ZYX", [0.3, pitch, roll])
    return accel_axes_tilt_variance_in_force_rad2(tuple(c_bn.as_matrix().ravel()), 0.0, 0.0, -G, sigma)


def _finite_difference_variance(roll, pitch, sigma):
    f = Rotation.from_euler("ZYX", [0.3, pitch, roll]).inv().apply([0.0, 0.0, -G])   # at rest, body frame
    return _variance_by_element(_levelled, f, sigma)


@pytest.mark.parametrize("roll_deg, pitch_deg", [(0, 0), (20, 0), (0, 15), (-25, 10), (40, -30), (5, 60)])
def test_partials_are_the_misaligned_accelerometers_levelling(roll_deg, pitch_deg):
    roll, pitch = math.radians(roll_deg), math.radians(pitch_deg)
    vr, vp = _at_rest_variance(roll, pitch, SIGMA_M_RAD)
    er, ep = _finite_difference_variance(roll, pitch, SIGMA_M_RAD)
    assert vr == pytest.approx(er, rel=1e-5)
    assert vp == pytest.approx(ep, rel=1e-5)


def test_worked_heel():
    s2 = SIGMA_M_RAD ** 2
    phi = math.radians(20.0)
    # heel φ, level pitch: roll error m_yz cos²φ − m_zy sin²φ; pitch error −m_xz cos φ − m_xy sin φ
    vr, vp = _at_rest_variance(phi, 0.0, SIGMA_M_RAD)
    assert vr == pytest.approx(s2 * (math.cos(phi) ** 4 + math.sin(phi) ** 4), rel=1e-12)
    assert vp == pytest.approx(s2, rel=1e-12)
    # level: σ_m on each
    assert _at_rest_variance(0.0, 0.0, SIGMA_M_RAD) == pytest.approx((s2, s2), rel=1e-12)
    assert _at_rest_variance(phi, 0.0, 0.0) == (0.0, 0.0)
    assert _at_rest_variance(phi, 0.0, math.nan) == (0.0, 0.0)


def _heeled_run(estimator=Ins, **params):
    """A still, heeled ins (or mekf) (20° roll, 5° pitch), 30 s at 100 Hz: its last estimate."""
    r = Rotation.from_euler("ZYX", [0.5, math.radians(5.0), math.radians(20.0)])    # body → NED
    f_b = r.inv().apply([0.0, 0.0, -G])
    m_b = r.inv().apply([20.0, 1.0, 45.0])
    est = estimator(**params)
    e = None
    for i in range(3000):
        e = est.update(make_sample(i * 0.01, np.zeros(3), f_b, m_b, flags=SampleFlags.NEW_DATA))
    return e


@pytest.mark.parametrize("estimator, rel", [(Ins, 1e-3), (Mekf, 1e-3)])
def test_the_filter_publishes_the_term_in_quadrature_and_the_same_estimate(estimator, rel):
    """ins and mekf both level on the accelerometer: their published roll and pitch σ carry its misalignment (mekf
    at the low-passed force they level on, gravity's here to within the estimate's error: rel 1e-3)."""
    on = _heeled_run(estimator)
    off = _heeled_run(estimator, accel_axes_tilt_sigma_rad=0.0)
    # the estimate itself is the same to the bit: only the published σ changes
    assert (on.roll_rad, on.pitch_rad, on.heading_true_rad) == (off.roll_rad, off.pitch_rad, off.heading_true_rad)
    np.testing.assert_array_equal(on.q_wxyz, off.q_wxyz)
    assert on.sigma_rpy_rad[2] == off.sigma_rpy_rad[2]
    # by hand at the estimate's attitude (≈ 20° heel, 5° pitch: the first-order terms of the partials)
    phi, th = on.roll_rad, on.pitch_rad
    assert abs(phi - math.radians(20.0)) < math.radians(0.5)
    cp, sp, cr, sr = math.cos(th), math.sin(th), math.cos(phi), math.sin(phi)
    # roll: m_yx f_x, m_yz f_z through ∂φ/∂f_y = −cos φ / cos θ; m_zx f_x, m_zy f_y through ∂φ/∂f_z = sin φ / cos θ
    var_roll = SIGMA_M_RAD ** 2 * ((cr / cp * sp) ** 2 + (cr / cp * cr * cp) ** 2
                                   + (sr / cp * sp) ** 2 + (sr / cp * sr * cp) ** 2)
    # pitch: ∂θ/∂f_x = cos θ (m_xy f_y, m_xz f_z), ∂θ/∂f_y = −sin θ sin φ (m_yx f_x, m_yz f_z),
    # ∂θ/∂f_z = −sin θ cos φ (m_zx f_x, m_zy f_y)
    var_pitch = SIGMA_M_RAD ** 2 * (cp ** 2 * cp ** 2 + (sp * sr) ** 2 * (sp ** 2 + (cr * cp) ** 2)
                                    + (sp * cr) ** 2 * (sp ** 2 + (sr * cp) ** 2))
    assert on.sigma_rpy_rad[0] ** 2 == pytest.approx(off.sigma_rpy_rad[0] ** 2 + var_roll, rel=rel)
    assert on.sigma_rpy_rad[1] ** 2 == pytest.approx(off.sigma_rpy_rad[1] ** 2 + var_pitch, rel=rel)
    assert on.sigma_rpy_rad[0] >= SIGMA_M_RAD * math.sqrt(cr ** 4 + sr ** 4) * 0.99


def _finite_difference_variance_in_force(c_bn: Rotation, f_b, sigma):
    """The roll and pitch variance a misaligned accelerometer leaves in an attitude levelled on the force f_b (body):
    the attitude that puts the measured force (I + M) f_b along the true one in NED is C·R, R the least rotation
    taking the measured direction onto f_b's (scipy), its Euler roll and pitch differenced per element m_jk."""
    f = np.asarray(f_b, dtype=float)

    def roll_pitch(meas):
        rot, _ = Rotation.align_vectors([f], [meas])        # R: measured direction → f_b's (identity for f_b)
        e = (c_bn * rot).as_euler("ZYX")
        return e[2], e[1]

    return _variance_by_element(roll_pitch, f, sigma)


@pytest.mark.parametrize("roll_deg, pitch_deg, force_b", [
    (0, 0, (0.0, 0.0, -G)),                          # level, at rest
    (20, 5, None),                                   # heeled at rest: gravity's force
    (30, 0, (0.0, 0.0, -G / math.cos(math.radians(30.0)))),   # a coordinated 30° bank: the force on body z
    (45, 3, (0.4, 0.0, -G / math.cos(math.radians(45.0)))),   # a steeper one, braking a little
    (10, -8, (1.5, 2.0, -9.0)),                      # a car turning and accelerating
])
def test_the_term_in_any_force_is_the_levelled_attitudes_turn(roll_deg, pitch_deg, force_b):
    """The variance at the filter's specific force, against the attitude a misaligned accelerometer's force puts the
    levelling at (scipy's least rotation between the measured and true directions, Euler angles differenced); at
    rest it is the gravity-only closed form; in a coordinated turn the roll's is σ_m² whatever the bank."""
    c_bn = Rotation.from_euler("ZYX", [0.7, math.radians(pitch_deg), math.radians(roll_deg)])
    f_b = c_bn.inv().apply([0.0, 0.0, -G]) if force_b is None else np.asarray(force_b)
    f_n = c_bn.apply(f_b)
    vr, vp = accel_axes_tilt_variance_in_force_rad2(tuple(c_bn.as_matrix().ravel()), *f_n, SIGMA_M_RAD)
    er, ep = _finite_difference_variance_in_force(c_bn, f_b, SIGMA_M_RAD)
    assert vr == pytest.approx(er, rel=1e-4)
    assert vp == pytest.approx(ep, rel=1e-4)
    if force_b is None:
        # at rest: the gravity-levelling's finite differences (independent of the force's direction form)
        at_rest = _finite_difference_variance(math.radians(roll_deg), math.radians(pitch_deg), SIGMA_M_RAD)
        assert (vr, vp) == pytest.approx(at_rest, rel=1e-5)
    if roll_deg == 30:
        assert vr == pytest.approx(SIGMA_M_RAD ** 2, rel=1e-9)


def test_one_misalignment_figure_is_both_terms_default():
    """The heading's and the tilt's consider terms are the same physical figure, the accelerometer's misalignment
    1σ per off-diagonal element (0.1°, the simulated sensor's): one named constant is both parameters' default,
    and both keys stay (a sensor known per axis may set them apart)."""
    from ahrsd.estimator.accel_axes_tilt import ACCEL_MISALIGNMENT_SIGMA_RAD
    from ahrsd.estimator.ins import InsParams
    from ahrsd.simulation.errors import MISALIGN_SIGMA_RAD

    assert ACCEL_MISALIGNMENT_SIGMA_RAD == MISALIGN_SIGMA_RAD == math.radians(0.1)
    p = InsParams()
    assert p.accel_axes_heading_sigma_rad == p.accel_axes_tilt_sigma_rad == ACCEL_MISALIGNMENT_SIGMA_RAD
    apart = InsParams(accel_axes_heading_sigma_rad=0.0, accel_axes_tilt_sigma_rad=math.radians(0.2))
    assert apart.accel_axes_heading_sigma_rad == 0.0 and apart.accel_axes_tilt_sigma_rad == math.radians(0.2)
