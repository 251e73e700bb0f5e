"""The RTS smoother over the ins filter (estimator/ins_smoother.py): against the batch least-squares solution of
a linear-Gaussian system, the error-state bookkeeping, and on a simulated boat against the truth."""

from __future__ import annotations

import numpy as np
import pytest

from ahrsd.estimator import ins_core as core
from ahrsd.estimator.ins import Ins
from ahrsd.estimator.ins_smoother import RtsSmoother, SmoothingIns, nominal_difference


def _linear_system(rng, n=4, m=2, steps=40):
    """A time-varying linear-Gaussian system x_k = F_k x_{k−1} + w, z_k = H x_k + v, measured at 70 % of the
    steps."""
    f = [np.eye(n) + 0.1 * rng.standard_normal((n, n)) for _ in range(steps)]
    q = np.diag(rng.uniform(0.01, 0.1, n))
    h = rng.standard_normal((m, n))
    r = np.diag(rng.uniform(0.1, 0.5, m))
    m0, p0 = rng.standard_normal(n), np.diag(rng.uniform(0.5, 2.0, n))
    x = rng.multivariate_normal(m0, p0)
    measured = rng.random(steps) < 0.7
    measured[0] = measured[-1] = True
    z = []
    for k in range(steps):
        if k:
            x = f[k] @ x + rng.multivariate_normal(np.zeros(n), q)
        z.append(h @ x + rng.multivariate_normal(np.zeros(m), r))
    return f, q, h, r, m0, p0, measured, z


def _batch(f, q, h, r, m0, p0, measured, z):
    """The smoothed states and covariances as the solution of the whole stacked least-squares problem
    (information form): prior, dynamics and measurement residuals weighted by their inverse covariances."""
    n, steps = len(m0), len(z)
    big = np.zeros((n * steps, n * steps))
    rhs = np.zeros(n * steps)
    qi, ri = np.linalg.inv(q), np.linalg.inv(r)
    sl = [slice(n * k, n * (k + 1)) for k in range(steps)]
    big[sl[0], sl[0]] += np.linalg.inv(p0)
    rhs[sl[0]] += np.linalg.inv(p0) @ m0
    for k in range(1, steps):   # x_k − F_k x_{k−1}
        big[sl[k], sl[k]] += qi
        big[sl[k - 1], sl[k - 1]] += f[k].T @ qi @ f[k]
        big[sl[k], sl[k - 1]] -= qi @ f[k]
        big[sl[k - 1], sl[k]] -= f[k].T @ qi
    for k in range(steps):
        if measured[k]:
            big[sl[k], sl[k]] += h.T @ ri @ h
            rhs[sl[k]] += h.T @ ri @ z[k]
    cov = np.linalg.inv(big)
    est = np.linalg.solve(big, rhs)
    return [est[s] for s in sl], [cov[s, s] for s in sl]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rts_equals_the_batch_least_squares_solution(seed):
    """Closed-loop filtering (the correction folded into the nominal each epoch) and the smoother's bookkeeping,
    with steps without a measurement (Φ multiplied up) and nodes composed inside blocks, against the stacked
    problem solved at once."""
    rng = np.random.default_rng(seed)
    f, q, h, r, m0, p0, measured, z = _linear_system(rng)
    n = len(m0)
    sm = RtsSmoother(n)
    xhat, p = m0.copy(), p0.copy()
    post, ends = [], []
    for k in range(len(z)):
        if k:
            xhat, p = f[k] @ xhat, f[k] @ p @ f[k].T + q
            sm.propagate(f[k])
        if not measured[k]:
            continue
        gain = p @ h.T @ np.linalg.inv(h @ p @ h.T + r)
        dx = gain @ (z[k] - h @ xhat)
        p_post = (np.eye(n) - gain @ h) @ p
        end = k == 0 or k % 3 == 0 or k == len(z) - 1
        sm.node(k, p, p_post, dx, cut=k == 0, block_end=end)
        xhat, p = xhat + dx, p_post
        if end:
            post.append(xhat.copy())
            ends.append(k)
    t, s_post, s_pre, p_s = sm.smooth()
    assert list(t) == ends
    want_x, want_p = _batch(f, q, h, r, m0, p0, measured, z)
    for i, k in enumerate(ends):
        np.testing.assert_allclose(post[i] + s_post[i], want_x[k], rtol=0, atol=1e-9)
        np.testing.assert_allclose(p_s[i], want_p[k], rtol=0, atol=1e-9)
    # the last node: smoothed = filtered
    np.testing.assert_allclose(s_post[-1], 0.0, atol=1e-12)


def test_nominal_difference_inverts_the_closed_loop_correction():
    """The correction recovered from the nominal states before and after is the one the filter folded in (sign
    and frame of each block)."""
    rng = np.random.default_rng(3)
    ins = Ins()
    par = ins._par
    x = np.zeros(1, core.INS_STATE_DTYPE)[0]
    x["q"] = np.array([0.9, 0.1, -0.3, 0.2]) / np.linalg.norm([0.9, 0.1, -0.3, 0.2])
    x["vel_ned_m_s"] = [3.0, -1.0, 0.2]
    x["lat_rad"], x["lon_rad"], x["h_m"] = 0.9, 0.4, 35.0
    dx = rng.standard_normal(core.N_ERR) * np.r_[[1e-3] * 3, [0.1] * 3, [2.0] * 3, [1e-4] * 3, [1e-2] * 3,
                                                 [1e-3] * 9, [1e-2] * 5, [1e-3] * 2, [1e-3] * 2]
    after = x.copy()
    core._apply_correction(after, par, dx)
    np.testing.assert_allclose(nominal_difference(x, after, par), dx, rtol=1e-9, atol=1e-12)


def _boat(seconds=60.0, rate_hz=100.0, seed=1):
    from ahrsd.simulation import open_stream, simulate_gnss

    stream = open_stream("boat", rate_hz=rate_hz, seed=seed)
    block = stream.next_block(int(round(seconds * rate_hz)))
    return stream, block, simulate_gnss(block, rate_hz=5.0, seed=seed + 1000)


def _run(est, block, fixes):
    from ahrsd.core.sample import make_sample

    rp = np.empty((len(block.t_s), 3))
    j = 0
    for i, t in enumerate(block.t_s):
        while j < len(fixes) and fixes[j].t_s <= t:
            est.update_gnss(fixes[j])
            j += 1
        e = est.update(make_sample(t, block.gyro_rad_s[i], block.accel_m_s2[i], block.mag_ut[i]))
        rp[i] = e.roll_rad, e.pitch_rad, np.hypot(e.sigma_rpy_rad[0], e.sigma_rpy_rad[1])
    return rp


def test_smoother_levels_a_boat_better_than_the_filter():
    """60 s of the simulated boat, magnetometer off (as the calibration's levelling): the recording leaves the
    filter's estimates unchanged, and the smoothed tilt is nearer the truth than the filter's."""
    from ahrsd.estimator.rotations import quat_to_euler

    stream, block, fixes = _boat()
    decl = stream.earth_field.declination_rad
    fwd = _run(Ins(declination_rad=decl, mag_enabled=False), block, fixes)
    est = SmoothingIns(declination_rad=decl, mag_enabled=False)
    rec = _run(est, block, fixes)
    np.testing.assert_array_equal(rec, fwd)
    assert est.gnss_counters.fused_velocity > 250 and est.gnss_counters.reset_velocity == 0
    roll_s, pitch_s, sigma_s = est.smoothed_roll_pitch()
    sigma_f = fwd[:, 2]
    truth = quat_to_euler(block.truth_q_wxyz)

    def tilt_rms_deg(roll, pitch, sel):
        return float(np.degrees(np.sqrt(np.mean(((roll - truth[:, 0]) ** 2 + (pitch - truth[:, 1]) ** 2)[sel]))))

    early, late = block.t_s >= 5.0, block.t_s >= 30.0
    forward, smoothed = tilt_rms_deg(fwd[:, 0], fwd[:, 1], early), tilt_rms_deg(roll_s, pitch_s, early)
    assert smoothed < 0.8 * forward, (forward, smoothed)   # measured 0.37 → 0.27°
    forward, smoothed = tilt_rms_deg(fwd[:, 0], fwd[:, 1], late), tilt_rms_deg(roll_s, pitch_s, late)
    assert smoothed < 0.9 * forward, (forward, smoothed)   # measured 0.38 → 0.28°
    # continuous across the fixes: the filter's corrections there are in the smoothed correction (s + dx)
    steps = np.hypot(np.diff(roll_s - truth[:, 0]), np.diff(pitch_s - truth[:, 1]))[block.t_s[1:] >= 10.0]
    at_fix = np.isin(block.t_s[1:], est.smoother.smooth()[0])[block.t_s[1:] >= 10.0]
    assert np.sqrt(np.mean(steps[at_fix] ** 2)) < 2.0 * np.sqrt(np.mean(steps[~at_fix] ** 2))
    # the smoothed 1σ is below the filter's
    assert np.all(np.isfinite(sigma_s))
    assert np.median(sigma_s[early]) < 0.9 * np.median(sigma_f[early])


def test_smoother_records_the_magnetometer_updates_within_the_samples():
    """With the magnetometer on, the heading updates happen inside a sample's step (the covariance epoch), not
    at a fix: each must be a node (an unrecorded one leaves its correction out of the smoothed one, and the
    next node's prior too small). Against the simulator's truth, 60 s of the boat: the smoothed tilt and yaw
    are nearer the truth than the filter's."""
    from ahrsd.estimator.rotations import quat_exp, quat_multiply, quat_to_euler

    stream, block, fixes = _boat()
    est = SmoothingIns(declination_rad=stream.earth_field.declination_rad, mag_enabled=True)
    _run(est, block, fixes)
    corr, _ = est.smoothed_corrections()
    q = est._rec[: est._n_rec]["q"]
    truth = quat_to_euler(block.truth_q_wxyz)
    sel = block.t_s >= 5.0

    def tilt_yaw_rms_deg(rpy):
        tilt = (rpy[:, 0] - truth[:, 0]) ** 2 + (rpy[:, 1] - truth[:, 1]) ** 2
        yaw = (rpy[:, 2] - truth[:, 2] + np.pi) % (2.0 * np.pi) - np.pi
        return np.degrees(np.sqrt(np.mean(tilt[sel]))), np.degrees(np.sqrt(np.mean(yaw[sel] ** 2)))

    tilt_f, yaw_f = tilt_yaw_rms_deg(quat_to_euler(q))
    tilt_s, yaw_s = tilt_yaw_rms_deg(quat_to_euler(quat_multiply(quat_exp(corr[:, core.E_TH:core.E_TH + 3]), q)))
    # the margins and what the step's magnetometer nodes left out gives: docs/estimator.md "Offline smoothing"
    assert tilt_s < 0.7 * tilt_f, (tilt_f, tilt_s)
    assert yaw_s < 0.5 * yaw_f, (yaw_f, yaw_s)
