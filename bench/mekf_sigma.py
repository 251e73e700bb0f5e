"""mekf's published σ against its error on simulated scenarios without GNSS: RMS roll/pitch/heading, the median of
the published 1σ and the share of samples whose error lies beyond 3σ, per axis, against simulator truth.

    .venv/bin/python bench/mekf_sigma.py                                   # every scenario, seed 0
    .venv/bin/python bench/mekf_sigma.py --scenarios level-turns boat --seeds 1 3   # held-out seeds
    .venv/bin/python bench/mekf_sigma.py --params fixed-wing --scenarios coordinated-turn plane

Samples go through the simulated chip and the real driver (bench/accuracy.py simulate_through_driver: perfect
magnetometer/accelerometer calibration, gyro bias left to the filter); σ is what `Mekf.step` publishes
(sigma_rpy_rad: roll, pitch, yaw); the first --settle seconds are skipped.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.accuracy import simulate_through_driver  # noqa: E402

SCENARIOS = {"static": 60.0, "level-turns": 120.0, "coordinated-turn": 156.0, "boat": 180.0, "car": 180.0,
             "plane": 180.0, "auv-out-and-back": 120.0, "tumble": 60.0}


def run(scenario: str, seconds: float, seed: int, settle_s: float, params=None):
    """(RMS roll, pitch, heading error °, median published 1σ roll, pitch, yaw °, % beyond 3σ per axis) of mekf
    on one simulated run."""
    from scipy.spatial.transform import Rotation

    from ahrsd.core.sample import ImuSample
    from ahrsd.estimator.mekf import Mekf

    d, truth, decl = simulate_through_driver(scenario, seconds, seed)
    # the accelerometer is calibrated exactly here (turn-on bias removed; the 0.2 mg in-run bias is 0.01°)
    f = Mekf(params=params, accel_bias_sigma_m_s2=0.0)
    n = len(d.t_s)
    q = np.full((n, 4), np.nan)
    sig = np.full((n, 3), np.nan)
    for i in range(n):
        v = f.step(ImuSample(d.t_s[i], d.gyro_rad_s[i], d.accel_m_s2[i], d.mag_ut[i], int(d.flags[i])))
        if v.valid:
            s = v.snapshot()
            q[i] = s.q_wxyz
            sig[i] = s.sigma_rpy_rad
    ok = (d.t_s - d.t_s[0] >= settle_s) & np.all(np.isfinite(q), axis=1)

    def rot(x):
        return Rotation.from_quat(np.concatenate([x[:, 1:], x[:, :1]], axis=1))

    # the estimate is magnetic: add the site's declination (as bench/accuracy.py), then the error rotation in NED,
    # its horizontal part turned into the truth's heading frame (roll, pitch) and its down part (heading)
    r_true = rot(truth[ok])
    e = (Rotation.from_rotvec([0.0, 0.0, decl]) * rot(q[ok]) * r_true.inv()).as_rotvec()
    c = r_true.as_matrix()
    yaw = np.arctan2(c[:, 1, 0], c[:, 0, 0])
    err = np.stack([np.cos(yaw) * e[:, 0] + np.sin(yaw) * e[:, 1], -np.sin(yaw) * e[:, 0] + np.cos(yaw) * e[:, 1],
                    e[:, 2]], axis=1)
    s = sig[ok]
    rms = np.degrees(np.sqrt(np.mean(err**2, axis=0)))
    beyond = 100.0 * np.mean(np.abs(err) > 3.0 * s, axis=0)
    return rms, np.degrees(np.median(s, axis=0)), beyond


def main(argv=None) -> int:
    from ahrsd.estimator.mekf import DEFAULT_MEKF_PARAMS, FIXED_WING_MEKF_PARAMS

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS))
    ap.add_argument("--seeds", nargs="+", type=int, default=[0])
    ap.add_argument("--seconds", type=float, default=None, help="override each scenario's length")
    ap.add_argument("--settle", type=float, default=20.0)
    ap.add_argument("--params", choices=("default", "fixed-wing"), default="default")
    args = ap.parse_args(argv)
    params = FIXED_WING_MEKF_PARAMS if args.params == "fixed-wing" else DEFAULT_MEKF_PARAMS
    print(f"{'scenario':17s} {'seed':>4s}  RMS roll/pitch/head (°)  σ median r/p/y (°)  beyond 3σ r/p/h (%)")
    for scen in args.scenarios:
        for seed in args.seeds:
            rms, med, beyond = run(scen, args.seconds or SCENARIOS[scen], seed, args.settle, params)
            print(f"{scen:17s} {seed:4d}  {rms[0]:5.2f} {rms[1]:5.2f} {rms[2]:5.2f}        "
                  f"{med[0]:5.2f} {med[1]:5.2f} {med[2]:5.2f}   {beyond[0]:5.1f} {beyond[1]:5.1f} {beyond[2]:5.1f}",
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
