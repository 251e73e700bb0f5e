"""mekf's σ against its error on simulated scenarios: RMS roll/pitch/heading and the share of samples whose error
lies beyond 3σ (σ from the filter's covariance, per NED axis), against simulator truth.

    .venv/bin/python bench/mekf_sigma.py                                   # level-turns, coordinated-turn,
    .venv/bin/python bench/mekf_sigma.py --scenarios level-turns --seeds 0 1 2   # auv-out-and-back, static, tumble

Samples go through the simulated chip and the real driver (bench/accuracy.py simulate_through_driver: perfect
magnetometer/accelerometer calibration, gyro bias left to the filter); the first --settle seconds are skipped.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.accuracy import simulate_through_driver  # noqa: E402

SCENARIOS = {"level-turns": 120.0, "coordinated-turn": 156.0, "auv-out-and-back": 120.0, "static": 60.0,
             "tumble": 60.0}


def run(scenario: str, seconds: float, seed: int, settle_s: float, params=None):
    """(rms roll, pitch, heading °, share beyond 3σ tilt, heading) of mekf on one simulated run."""
    from scipy.spatial.transform import Rotation

    from ahrsd.core.sample import ImuSample
    from ahrsd.estimator.mekf import Mekf

    d, truth, decl = simulate_through_driver(scenario, seconds, seed)
    f = Mekf(params=params)
    n = len(d.t_s)
    q = np.full((n, 4), np.nan)
    sig = np.full((n, 3), np.nan)
    for i in range(n):
        est = f.update(ImuSample(d.t_s[i], d.gyro_rad_s[i], d.accel_m_s2[i], d.mag_ut[i]))
        if est is not None:
            q[i] = est.q_wxyz
            sig[i] = f.covariance.diagonal()[:3] ** 0.5
    ok = (d.t_s - d.t_s[0] >= settle_s) & np.all(np.isfinite(q), axis=1)

    def rot(x):
        return Rotation.from_quat(np.concatenate([x[:, 1:], x[:, :1]], axis=1))

    # the estimate is magnetic: add the site's declination (as bench/accuracy.py), then the error rotation in NED
    r_true = rot(truth[ok])
    e = (Rotation.from_rotvec([0.0, 0.0, decl]) * rot(q[ok]) * r_true.inv()).as_rotvec()
    c = r_true.as_matrix()
    yaw = np.arctan2(c[:, 1, 0], c[:, 0, 0])
    roll = np.cos(yaw) * e[:, 0] + np.sin(yaw) * e[:, 1]
    pitch = -np.sin(yaw) * e[:, 0] + np.cos(yaw) * e[:, 1]
    rms = np.degrees(np.sqrt(np.mean(np.stack([roll, pitch, e[:, 2]], 1) ** 2, axis=0)))
    s = sig[ok]
    beyond_tilt = np.mean((np.abs(e[:, 0]) > 3 * s[:, 0]) | (np.abs(e[:, 1]) > 3 * s[:, 1]))
    beyond_head = np.mean(np.abs(e[:, 2]) > 3 * s[:, 2])
    return (*rms, 100 * beyond_tilt, 100 * beyond_head, np.degrees(np.median(s, axis=0)))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS))
    ap.add_argument("--seeds", nargs="+", type=int, default=[0])
    ap.add_argument("--seconds", type=float, default=None, help="override each scenario's length")
    ap.add_argument("--settle", type=float, default=20.0)
    args = ap.parse_args(argv)
    print(f"{'scenario':17s} {'seed':>4s} {'roll':>6s} {'pitch':>6s} {'head':>6s}  {'>3σ tilt':>8s} {'>3σ head':>8s}"
          f"  σ median N/E/D (°)")
    for scen in args.scenarios:
        for seed in args.seeds:
            r, p, h, bt, bh, sm = run(scen, args.seconds or SCENARIOS[scen], seed, args.settle)
            print(f"{scen:17s} {seed:4d} {r:6.2f} {p:6.2f} {h:6.2f}  {bt:7.1f}% {bh:7.1f}%  "
                  f"{sm[0]:.2f}/{sm[1]:.2f}/{sm[2]:.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
