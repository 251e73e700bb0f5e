"""One GNSS velocity row through ins_core._gated_update, beside the ordinary Kalman gain worked out with numpy: what
the tests of the states a wrong heading must not teach compare (test_accel_bias_heading, test_tilt_unknown_heading)."""

from __future__ import annotations

import math

import numpy as np

from ahrsd.estimator import ins_core as core
from ahrsd.estimator.ins import InsParams


def gated_velocity_update(learn: float, *, seed: int, velocity_axis: int, innovation_m_s: float):
    """Fuse one velocity component (`velocity_axis` 0 north, 1 east) with innovation `innovation_m_s` into a random
    full covariance (every state correlated with the velocity), `accel_bias_learn` = `learn` (0: the heading is not
    known). Returns (the kernel's state correction, the ordinary gain's correction k·ν computed here)."""
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(core.N_ERR, core.N_ERR)) * 0.1
    P = a @ a.T + np.eye(core.N_ERR) * 0.01
    par = InsParams().to_array(0.0)
    par[0]["accel_bias_learn"] = learn
    gate = np.zeros(1, core.GNSS_GATE_DTYPE)
    gate[0]["rejected_since_s"] = math.nan
    row = core.E_V + velocity_axis
    h = np.zeros((3, core.N_ERR))
    h[0, row] = 1.0
    nu = np.array([innovation_m_s, 0.0, 0.0])
    var = np.array([0.04, 0.04, 0.04])
    dx = np.zeros(core.N_ERR)
    P_before = P.copy()
    # the gate on the same row (no antenna-arm term: lever_arm_consider.py adds one only to the update's rows)
    res = core._gated_update(gate[0], P, par[0], h, nu, var, 1, dx, 1.0, False, core.R_VEL_FUSED,
                             core.R_VEL_REJECTED, core.R_VEL_RESET, h, nu, var)
    assert res == core.R_VEL_FUSED
    k = P_before[:, row] / (P_before[row, row] + var[0])   # the ordinary gain (numpy)
    return dx, k * nu[0]
