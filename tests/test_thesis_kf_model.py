"""The thesis filter's time update is the model its docstring writes (estimator/thesis_kf.py): A, B and
F = I + AΔt + ½A²Δt² built here from the 3×3 blocks, independently of the filter's flat index tables."""

from __future__ import annotations

import numpy as np

from ahrsd.estimator.thesis_kf import ThesisKf


def _skew(v):
    """[v×]"""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def test_the_time_update_is_the_documented_block_model():
    rng = np.random.default_rng(5)
    kf = ThesisKf()
    m, g, b = rng.normal(20.0, 10.0, 3), rng.normal(0.0, 5.0, 3), rng.normal(0.0, 0.01, 3)
    w = rng.normal(0.0, 0.5, 3)
    x0 = np.concatenate([m, g, b])
    p_half = rng.normal(0.0, 1.0, (9, 9))
    p0 = p_half @ p_half.T
    kf._x = x0.copy()
    kf._p = p0.copy()
    kf._rate_list = list(w)
    dt = 0.01
    kf._predict(dt)

    tau = kf.params.bias_time_constant_s
    z3, i3 = np.zeros((3, 3)), np.eye(3)
    # A = [[−[ω×], 0, −[m×]], [0, −[ω×], −[g×]], [0, 0, −I/τ_w]],  B = [[−[m×], 0], [−[g×], 0], [0, I/τ_w]]
    a = np.block([[-_skew(w), z3, -_skew(m)], [z3, -_skew(w), -_skew(g)], [z3, z3, -i3 / tau]])
    bm = np.block([[-_skew(m), z3], [-_skew(g), z3], [z3, i3 / tau]])
    f = np.eye(9) + a * dt + 0.5 * (a * dt) @ (a * dt)
    np.testing.assert_allclose(kf._x, f @ x0, rtol=1e-12, atol=1e-12)
    p_expected = f @ p0 @ f.T + bm @ np.diag(kf.params.q_diag) @ bm.T * dt
    np.testing.assert_allclose(kf._p, p_expected, rtol=1e-10, atol=1e-12)
