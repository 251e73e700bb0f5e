"""Compile an estimator's numba kernels before the sample loop starts.

numba compiles a kernel on its first call (cached on disk afterwards, under `NUMBA_CACHE_DIR` in the service
unit). On the first start after an install that takes 10–20 s; inside the loop it would stall the samples and
let the GNSS fixes that queued meanwhile go stale (rejected). Running a throwaway estimator through
initialisation, a few samples and one fix compiles or loads every kernel the loop will call.
"""

from __future__ import annotations

import numpy as np

from ahrsd.core.gnss import GnssFix
from ahrsd.core.sample import make_sample

from . import make_estimator
from .base import GnssAidedEstimator

SAMPLE_PERIOD_S = 1.0 / 100.0
N_SAMPLES = 300                 # past initialisation, the first fix's delay and its fusion


def warm_up(name: str) -> None:
    """Run a throwaway `name` estimator on a level, still vehicle with one GNSS fix; the result is discarded."""
    est = make_estimator(name)
    accel_m_s2 = np.array([0.0, 0.0, -9.81])
    mag_ut = np.array([20.0, 0.0, 45.0])
    gyro_rad_s = np.zeros(3)
    has_gnss = isinstance(est, GnssAidedEstimator)
    for i in range(N_SAMPLES):
        t_s = i * SAMPLE_PERIOD_S
        est.update(make_sample(t_s, gyro_rad_s, accel_m_s2, mag_ut))
        if has_gnss and i % 20 == 10:
            est.update_gnss(GnssFix(t_s=t_s - 0.1, lat_deg=52.0, lon_deg=4.0, alt_m=0.0,
                                    vel_ned_m_s=np.zeros(3), h_acc_m=2.5, v_acc_m=5.0, s_acc_m_s=0.1))
