"""The vertical gyro bias from the magnetometer's turning (estimator/mag_rotation.py), against a bias put into a
synthetic straight leg: the vehicle rolls and pitches in waves, its magnetometer carries a strong hard and soft
iron the estimator is not told about, and its gyro turns the heading by the bias."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.estimator.mag_rotation import MagRotationBias, rotation_vector_step
from ahrsd.estimator.rotations import rotvec_to_dcm

B_NED_UT = np.array([24.0, 5.5, -51.4])          # a southern-hemisphere field: dip −63°
HARD_UT = np.array([-31.0, 24.0, -18.0])
SOFT = np.array([[0.93, -0.06, 0.04], [0.03, 1.09, -0.05], [-0.05, 0.02, 0.96]])
DEG_H = math.radians(1.0) / 3600.0


def _attitude(t):
    """Body → NED on a straight leg in waves: heading 40° with a slow 0.3° wander, roll 4°, pitch 2°."""
    yaw = 40.0 + 0.3 * math.sin(2 * math.pi * t / 23.0)
    roll = 4.0 * math.sin(2 * math.pi * t / 6.0)
    pitch = 2.0 * math.sin(2 * math.pi * t / 5.0 + 1.0)
    return Rotation.from_euler("ZYX", [yaw, pitch, roll], degrees=True).as_matrix()


def _window(bias_rad_s, seed=1, heading_offset_deg=2.0, est=None, att_cov=None, soft_iron=None):
    """Checks at 5 Hz for 30 s; the gyro's rotation between checks is the true one turned further about body z by
    the bias (estimate 0); the filter's attitude has the true tilt and a heading `heading_offset_deg` off. `est`: the
    window to feed (a fresh one without gyro noise by default); `att_cov`: the filter's attitude covariance it is
    told (NED; 1° on each axis by default); `soft_iron`: the learned soft iron it is told (I by default)."""
    att_cov = np.eye(3) * math.radians(1.0) ** 2 if att_cov is None else att_cov
    rng = np.random.default_rng(seed)
    est = MagRotationBias(gyro_noise_rad_s_rthz=0.0) if est is None else est
    off = Rotation.from_euler("z", heading_offset_deg, degrees=True).as_matrix()
    out = None
    t_prev = None
    for k in range(151):
        t = 0.2 * k
        c_true = _attitude(t)
        m = SOFT @ (c_true.T @ B_NED_UT) + HARD_UT + rng.normal(0.0, 0.1, 3)
        step = np.eye(3)
        if t_prev is not None:
            dt = t - t_prev
            step = _attitude(t_prev).T @ c_true @ Rotation.from_euler("z", bias_rad_s * dt).as_matrix()
        else:
            dt = 0.0
        told_soft = np.eye(3) if soft_iron is None else soft_iron
        out = est.add(t, m, off @ c_true, B_NED_UT, step, 0.0, dt, told_soft, 0.1, att_cov, math.radians(0.2)) or out
        t_prev = t
    return out


def test_the_window_sees_the_bias_through_an_iron_it_was_not_told_of():
    for bias_deg_h in (-236.0, 150.0):
        got, var = _window(bias_deg_h * DEG_H)
        sigma = math.sqrt(var)
        assert abs(got - bias_deg_h * DEG_H) < 3.0 * sigma, (got / DEG_H, sigma / DEG_H)
        # informative: far below the ±0.5 °/s a bias starts at
        assert sigma < 150.0 * DEG_H


def test_no_bias_is_seen_where_there_is_none():
    got, var = _window(0.0, seed=2)
    assert abs(got) < 3.0 * math.sqrt(var)


def test_a_windows_terms_are_its_variance_term_by_term():
    # MagRotationBias.terms (what bench/yaw_drift_trace.py --terms prints): they add up to the variance the fit
    # returned, the gyro-noise and tilt terms are the random walk's 6 q² / (5 T) and (√2·tan|dip|·σ_tilt / T)² worked
    # out here from the window's own inputs, and the tilt σ at the start is the 1° it was given
    q = 0.0015      # rad/s/√Hz: the gyro-noise term is then the window's largest but one
    est = MagRotationBias(gyro_noise_rad_s_rthz=q)
    _, var = _window(150.0 * DEG_H, est=est)
    scatter, scale, soft, attitude, walk, tilt, r1, att_sigma = est.terms
    assert math.isclose(scatter + scale + soft + attitude + walk + tilt, var, rel_tol=1e-12)
    assert min(scatter, scale, soft, attitude, walk, tilt) >= 0.0 and 0.0 <= r1 <= 0.95
    span = est.span_s
    tan_dip = abs(B_NED_UT[2]) / math.hypot(B_NED_UT[0], B_NED_UT[1])
    assert math.isclose(walk, 6.0 * q * q / (5.0 * span), rel_tol=1e-12)
    assert math.isclose(tilt, (math.sqrt(2.0) * tan_dip * math.radians(0.2) / span) ** 2, rel_tol=1e-12)
    assert att_sigma == math.radians(1.0) and attitude > 0.0 and scatter > 0.0


def test_a_window_takes_the_start_attitude_per_body_axis_and_waits_for_the_tilt_only():
    # a heading known to 10° and a tilt to 0.2° (the filter's covariance in NED): the window is fitted (the tilt is
    # what it waits for), its attitude term is the covariance turned into the body at the start through the fit's
    # slopes (worked out here with scipy's attitude of the start, the one the window was given), far below the
    # term of a 10° σ on every axis, and the bias is still found within its 3σ
    bias = 150.0 * DEG_H
    cov = np.diag([math.radians(0.2) ** 2, math.radians(0.2) ** 2, math.radians(10.0) ** 2])
    est = MagRotationBias(gyro_noise_rad_s_rthz=0.0)
    got, var = _window(bias, est=est, att_cov=cov)
    attitude = est.terms[3]
    c0 = Rotation.from_euler("z", 2.0, degrees=True).as_matrix() @ _attitude(0.0)
    t = np.array([s[0] for s in est.samples])       # the slope is the same from any origin
    att = est.sensitivities()[1]
    slopes = (t - t.mean()) @ (att - att.mean(axis=0)) / float((t - t.mean()) @ (t - t.mean()))
    assert math.isclose(attitude, float(slopes @ (c0.T @ cov @ c0) @ slopes), rel_tol=1e-9)
    assert attitude < 0.1 * math.radians(10.0) ** 2 * float(slopes @ slopes)
    assert abs(got - bias) < 3.0 * math.sqrt(var)
    assert est.terms[7] == math.radians(0.2)
    # a tilt above the 5° limit: no window
    assert _window(bias, att_cov=np.diag([math.radians(6.0) ** 2, 1e-6, 1e-6])) is None


def test_the_sensitivities_made_together_are_each_checks_own_to_rounding():
    """`sensitivities` makes every check's soft-iron and attitude rows at once at the fit: each equals what the check
    makes alone from what it kept (w, d, |w|², ΔCᵀ − I, A), the soft-iron row w_i d_j / |w|² and the attitude
    row −(A·(ΔCᵀ − I)·(e_i × v₀))·w / |w|², to rounding (the window's fit does not change with the batching). Not
    bit for bit: numpy picks its SIMD loops by the machine's CPU (AVX-512 on one kind here), and a stacked matmul
    may then round in another order than one product at a time (the last bit differed on an Intel Xeon, not on
    an AMD EPYC)."""
    est = MagRotationBias(gyro_noise_rad_s_rthz=0.0)
    _window(150.0 * DEG_H, est=est, soft_iron=SOFT)
    soft, att = est.sensitivities()
    assert len(est.samples) > 100
    for k, (_, _, _, _, w, d, ww, rt_i, a) in enumerate(est.samples):
        np.testing.assert_allclose(soft[k], (w[:, None] * d[None, :]).reshape(9) / ww, rtol=1e-12, atol=0.0)
        np.testing.assert_allclose(att[k], np.array([-(a @ (rt_i @ e)) @ w / ww for e in est.v0_moves_ut]),
                                   rtol=1e-12, atol=1e-18)
    assert np.all(np.abs(att) > 0.0) and np.all(np.isfinite(att))


def test_the_rotation_vector_carries_the_coning_term():
    """Rolling and pitching a quarter period apart turns the body about z (coning): the accumulated rotation
    vector, turned into a matrix, matches the product of the per-sample rotations (scipy) to 1e-5 rad, where the
    plain sum of the rates misses it (8e-4 rad)."""
    dt = 0.001
    theta = np.zeros(3)
    plain = np.zeros(3)
    c = np.eye(3)
    for k in range(200):
        t = k * dt
        w = np.array([0.5 * math.cos(2 * math.pi * t / 0.2), 0.5 * math.sin(2 * math.pi * t / 0.2), 0.0])
        rotation_vector_step(theta, w[0], w[1], w[2], dt)
        plain += w * dt
        c = c @ Rotation.from_rotvec(w * dt).as_matrix()
    truth = Rotation.from_matrix(c)
    assert (Rotation.from_matrix(rotvec_to_dcm(theta)) * truth.inv()).magnitude() < 1e-5
    assert (Rotation.from_rotvec(plain) * truth.inv()).magnitude() > 1e-4


class _WindowsSeen(MagRotationBias):
    """The windows as Ins feeds them, with what it knew then: each check's tilt 1σ (the last argument, or what the
    function there gives), the filter's covariance of the tilt and the accelerometer bias (δθ_N, δθ_E, b_x,
    b_y, b_z) at that check, and the tilt 1σ the window's fit took if the check completed one (else None)."""

    def __init__(self, est, seen: list, **kw):
        super().__init__(**kw)
        self.est, self.seen = est, seen

    def add(self, *args):
        from ahrsd.estimator import ins_core as core

        rows = [core.E_TILT_N, core.E_TILT_E, core.E_BA, core.E_BA + 1, core.E_BA + 2]
        sigma = args[-1]() if callable(args[-1]) else args[-1]     # Ins gives a function: asked at a fit only
        p = self.est._P[np.ix_(rows, rows)].copy()
        out = super().add(*args)
        self.seen.append((sigma, p, None if out is None else self.tilt_sigma_rad))
        return out


def _vertical_bias_error_deg_h(on: bool, windows: list | None = None) -> float:
    """RMS of the filter's vertical gyro bias less the simulator's turn-on bias from 180 s, °/h: the held-out
    boat (in-sample seed 12) without a magnetometer calibration, 280 s. `windows`: appended with, at each heading
    check, the tilt 1σ Ins gives the magnetometer-rotation window and the covariance of the tilt and the
    accelerometer bias (δθ_N, δθ_E, b_x, b_y, b_z) then."""
    from ahrsd.core.sample import SampleFlags, make_sample
    from ahrsd.estimator.ins import Ins
    from ahrsd.simulation import SensorErrors
    from bench.vehicle_accuracy import HONESTY_SITES, simulate_vehicle

    site, iron = HONESTY_SITES["held-out"]
    run = simulate_vehicle("boat", 280.0, 12, site, mag="uncalibrated", iron=iron)
    truth = SensorErrors.adis16405(12).gyro_bias_rad_s[2]
    est = Ins(declination_rad=run.declination_rad, mag_rotation_gyro_bias=on)
    if windows is not None:
        est._heading._mag_rotation = _WindowsSeen(
            est, windows, gyro_noise_rad_s_rthz=est._heading._mag_rotation.gyro_noise_rad_s_rthz)
    # the fixes received by each sample's time (they arrive in order)
    received = np.searchsorted([f.extra["t_rx_s"] for f in run.fixes], run.t_s, side="right")
    errs = []
    for k, t in enumerate(run.t_s):
        for fix in run.fixes[received[k - 1] if k else 0:received[k]]:
            est.update_gnss(fix)
        # step, not update: the bias is read, no estimate (estimator/estimate_view.py: building none changes none)
        est.step(make_sample(t, run.gyro_rad_s[k], run.accel_m_s2[k], run.mag_ut[k], flags=SampleFlags.NEW_DATA))
        if t > 180.0 and k % 200 == 0:
            errs.append((est.gyro_bias_rad_s[2] - truth) / DEG_H)
    return float(np.sqrt(np.mean(np.square(errs))))


@pytest.fixture(scope="module")
def held_out_boat():
    """(bias error on, off, the windows' tilt σ and covariances with it on): one run each."""
    windows = []
    on = _vertical_bias_error_deg_h(True, windows)
    return on, _vertical_bias_error_deg_h(False), windows


def test_ins_learns_the_vertical_gyro_bias_from_the_magnetometer_turning(held_out_boat):
    """Without a calibration the magnetometer's heading is not trusted and the GNSS sees the yaw only in turns:
    the vertical gyro bias stays tens of °/h off (39.5 °/h RMS at 180–280 s, measured; 42.9 °/h while the
    magnetometer was still fused during the iron learning, 54 °/h before that). The field's turning nearly halves
    it (22.6 °/h); the simulator's in-run instability (25 °/h) is part of both."""
    on, off, _ = held_out_boat
    assert on < 30.0
    assert off > 1.5 * on


def test_ins_gives_the_windows_the_tilt_error_the_accelerometer_bias_leaves(held_out_boat):
    """The tilt σ of a window's tilt term is the conditional σ of the tilt given the accelerometer bias, here from
    the precision matrix (the inverse of the inverse's tilt block: another route than the Schur complement), at
    every check and in the fit of each window a check completes (the σ at that check), and on this boat well under
    the whole tilt σ (the bias explains most of the filter's tilt uncertainty)."""
    _, _, windows = held_out_boat
    assert len(windows) > 500
    ratios = []
    fits = 0
    for sigma, p, fitted in windows:
        conditional = np.linalg.inv(np.linalg.inv(p)[:2, :2])
        expected = math.sqrt(max(conditional[0, 0], conditional[1, 1]))
        assert sigma == pytest.approx(expected, rel=1e-6)
        ratios.append(sigma / math.sqrt(max(p[0, 0], p[1, 1])))
        if fitted is not None:      # the window completed here was fitted with the σ at this check
            assert fitted == pytest.approx(expected, rel=1e-6)
            fits += 1
    assert np.median(ratios) < 0.7
    assert fits > 5


def test_the_window_tilt_sigma_is_what_the_bias_does_not_explain():
    """Samples of a tilt error made of a part a body-frame accelerometer bias explains (L·b, common to both ends of a
    window) and a part it does not (r): the function's σ is the σ of what a least-squares fit of the tilt on the
    bias leaves, within sampling error, and the change of the tilt between two ends that share b is √2 times it.
    Uncorrelated with the bias, it is the whole tilt σ."""
    from ahrsd.estimator.mag_rotation import window_tilt_sigma_rad

    rng = np.random.default_rng(35)
    n = 60_000
    p_bias = np.diag([0.02, 0.03, 0.05]) ** 2
    lever = np.array([[0.0, -0.10, 0.01], [0.10, 0.0, -0.02]])      # rad per m/s²: b/g across the two tilt axes
    r_sigma = np.radians([0.05, 0.08])
    bias = rng.multivariate_normal(np.zeros(3), p_bias, n)
    ends = [bias @ lever.T + rng.normal(0.0, 1.0, (n, 2)) * r_sigma for _ in range(2)]
    joint = np.cov(np.hstack([ends[0], bias]).T)
    sigma = window_tilt_sigma_rad(joint[:2, :2], joint[:2, 2:], joint[2:, 2:])
    fit, *_ = np.linalg.lstsq(np.hstack([bias, np.ones((n, 1))]), ends[0], rcond=None)
    left = ends[0] - np.hstack([bias, np.ones((n, 1))]) @ fit
    assert sigma == pytest.approx(np.max(left.std(axis=0)), rel=0.01)
    assert sigma == pytest.approx(max(r_sigma), rel=0.02)
    assert np.max((ends[1] - ends[0]).std(axis=0)) == pytest.approx(math.sqrt(2.0) * sigma, rel=0.02)
    assert sigma < 0.5 * math.sqrt(max(joint[0, 0], joint[1, 1]))
    apart = np.cov(np.hstack([rng.normal(0.0, 1.0, (n, 2)) * r_sigma, bias]).T)
    whole = math.sqrt(max(apart[0, 0], apart[1, 1]))
    assert window_tilt_sigma_rad(apart[:2, :2], apart[:2, 2:], apart[2:, 2:]) == pytest.approx(whole, rel=0.02)


def test_the_window_start_cross_product_is_numpys_to_the_bit():
    """`_cross` (the window start's B × e_z and e_i × v₀, four per start) gives np.cross's float64 result exactly:
    the same products and differences in the same order, over magnitudes from 1e-6 to 1e6, signed zeros included."""
    from ahrsd.estimator.mag_rotation import _cross

    rng = np.random.default_rng(28)
    vectors = [np.eye(3)[i] for i in range(3)] + [np.array([0.0, -0.0, 1.0]), np.array([-0.0, 0.0, -0.0])]
    vectors += [rng.normal(size=3) * 10.0 ** rng.uniform(-6, 6) for _ in range(400)]
    for a in vectors[:32]:
        for b in vectors:
            assert _cross(a, b).tobytes() == np.cross(a, b).tobytes(), (a, b)
