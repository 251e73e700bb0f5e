"""bench.vehicle_accuracy's `ins` run with the estimate built at every n-th sample only: the tests that judge the
heading and the horizon by their RMS, their share beyond 3σ or their worst value over a window read them at 50 Hz
as well as at 200 Hz, and building an AttitudeEstimate costs about a third of an aided run's CPU.

The samples between are stepped (`Ins.step`) without building one, which changes no estimate: what a snapshot holds
does not depend on how often snapshots are taken (estimator/estimate_view.py; tests/test_published_heading.py
checks it on a run with yaw resets). The flags, which the view gives without a build, are kept for every sample:
YAW_RESET and GNSS_REJECTED are set on one estimate only."""

from __future__ import annotations

import dataclasses

import numpy as np

from bench.vehicle_accuracy import VehicleRun

EVERY = 4
"""At 200 SPS: an estimate every 20 ms."""


@dataclasses.dataclass
class ThinnedIns:
    run: VehicleRun              # the run at the samples read (sensor arrays, truth, times): the error measures apply
    index: np.ndarray            # those samples' indices in the whole run (every n-th, and the last)
    estimates: list              # the AttitudeEstimate of each sample read
    flags_every_sample: np.ndarray   # EstimateFlags ints of every sample of the whole run
    ins: object                  # the estimator after the last sample

    def detailed(self) -> dict:
        """run_ins_detailed's dict at the samples read (q, published yaw 1σ, heading state, flags, the ins)."""
        e = self.estimates
        return {"q": np.array([x.q_wxyz for x in e]), "sigma_yaw_rad": np.array([x.sigma_rpy_rad[2] for x in e]),
                "heading_state": np.array([int(x.heading_state) for x in e], dtype=np.int8),
                "flags": self.flags_every_sample[self.index], "ins": self.ins}


def thinned_run(run: VehicleRun, index: np.ndarray) -> VehicleRun:
    """`run` at the samples `index` (its fixes stay whole)."""
    vel = None if run.truth_vel_ned_m_s is None else run.truth_vel_ned_m_s[index]
    return dataclasses.replace(run, t_s=run.t_s[index], gyro_rad_s=run.gyro_rad_s[index],
                               accel_m_s2=run.accel_m_s2[index], mag_ut=run.mag_ut[index],
                               truth_q_wxyz=run.truth_q_wxyz[index], truth_vel_ned_m_s=vel)


def run_ins_thinned(run: VehicleRun, every: int = EVERY, **params) -> ThinnedIns:
    """As bench.vehicle_accuracy.run_ins_detailed (the same Ins, told the run's lever arm and calibration σ unless
    `params` say otherwise; each fix offered where it arrives among the samples), the estimate built at every
    `every`-th sample and the last."""
    from ahrsd.core.gnss import GnssFix
    from ahrsd.core.sample import SampleFlags, make_sample
    from ahrsd.estimator.ins import Ins
    from ahrsd.simulation import in_arrival_order

    est = Ins(declination_rad=run.declination_rad, **{"lever_arm_m": run.lever_arm_m,
                                                      "mag_calibration_sigma_rad": run.mag_calibration_sigma_rad,
                                                      **params})
    t, g, a, m = run.t_s, run.gyro_rad_s, run.accel_m_s2, run.mag_ut
    n = len(t)
    read = np.zeros(n, dtype=bool)
    read[::every] = True
    read[-1] = True
    flags = np.zeros(n, dtype=np.int64)
    estimates = []
    samples = (make_sample(t[k], g[k], a[k], m[k], flags=SampleFlags.NEW_DATA) for k in range(n))
    k = 0
    for item in in_arrival_order(samples, run.fixes):
        if isinstance(item, GnssFix):
            est.update_gnss(item)
            continue
        view = est.step(item)
        flags[k] = int(view.flags)
        if read[k]:
            estimates.append(view.snapshot())
        k += 1
        if k == n:
            break
    index = np.flatnonzero(read)
    return ThinnedIns(thinned_run(run, index), index, estimates, flags, est)
