"""The magnetometer reference's low-pass weight is kept between samples (estimator/mag_heading.py); it must be
1 − exp(−Δt/τ) for the Δt and τ of each call, also when either changes."""

from __future__ import annotations

import math

import numpy as np

from ahrsd.estimator import mag_heading as mag


def test_the_kept_reference_weight_follows_the_time_step_and_the_time_constant():
    ms = np.zeros(1, mag.MAG_HEADING_STATE_DTYPE)[0]
    mp = np.zeros(1, mag.MAG_HEADING_PARAMS_DTYPE)[0]
    for dt, tau in ((0.01, 10.0), (0.01, 10.0), (0.005, 10.0), (0.01, 10.0), (0.01, 2.0), (1 / 819.2, 2.0)):
        mp["ref_tau_s"] = tau
        assert mag._reference_weight(ms, mp, dt) == 1.0 - math.exp(-dt / tau), (dt, tau)
