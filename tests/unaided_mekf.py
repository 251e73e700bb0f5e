"""mekf run sample by sample (`update`, the one-sample path the daemon uses) over a simulated vehicle without
GNSS (bench/vehicle_accuracy.simulate_vehicle's VehicleRun): the published quaternion and 1σ of every sample,
for the tests that hold them against the simulator's truth."""

from __future__ import annotations

import numpy as np

from ahrsd.core.sample import SampleFlags, make_sample


def estimates_over(run, est) -> tuple[np.ndarray, np.ndarray]:
    """(q_wxyz (N, 4), sigma_rpy_rad (N, 3)) that `est` publishes for each sample of `run`, in order."""
    n = len(run.t_s)
    q = np.empty((n, 4))
    sig = np.empty((n, 3))
    for k in range(n):
        e = est.update(make_sample(run.t_s[k], run.gyro_rad_s[k], run.accel_m_s2[k], run.mag_ut[k],
                                   flags=SampleFlags.NEW_DATA))
        q[k] = e.q_wxyz
        sig[k] = e.sigma_rpy_rad
    return q, sig
