"""How much mekf's published heading 1σ depends on the sample the filter starts on: the same simulated boat
(`level-turns`, the README tour's `ahrsd run --sim level-turns`), its magnetometer calibrated right and stating a
0.09° figure as the tour's calibration does, through the daemon's pipeline started 0, 3, 6 … samples into the
stream (a daemon's start lands anywhere in the chip's sample stream). Prints, per start, the peak heading 1σ from
5 s after the start, when it occurs, the heading RMS against the simulator's truth and the share beyond 3σ;
then the peaks' spread over the starts (docs/estimator.md "What the filter's own bias learning explains").

    .venv/bin/python bench/start_phase_sigma.py --seed 0 --offsets 0 3 6 12 18 24 48 96 200
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from ahrsd.calibration.heading_trust import calibration_heading_sigma_rad
from ahrsd.calibration.models import Calibration, MagModel
from ahrsd.core.sample import SampleFlags, make_sample
from ahrsd.daemon.pipeline import Pipeline
from ahrsd.estimator.mekf import Mekf
from ahrsd.simulation import open_stream


def _truth_yaw_rad(q) -> float:
    w, x, y, z = (float(v) for v in q)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def one_start(seed: int, offset: int, run_s: float):
    """(peak σ deg, its time s, heading RMS deg, share beyond 3σ %) of one start, from 5 s after it."""
    stream = open_stream("level-turns", seed=seed)
    e = stream.errors
    cal = Calibration.identity().with_sensor("mag", MagModel(e.hard_iron_ut, np.linalg.inv(e.soft_iron)),
                                             method="bench", heading_std_deg=0.09, offset_std_deg=0.09)
    est = Mekf(declination_rad=stream.earth_field.declination_rad)
    est.set_mag_calibration_sigma(calibration_heading_sigma_rad(cal))
    pipe = Pipeline(est, cal)
    k, t0, rows = 0, None, []
    while True:
        b = stream.next_block(4096)
        for i in range(len(b.t_s)):
            k += 1
            if k <= offset:
                continue
            t = float(b.t_s[i])
            t0 = t if t0 is None else t0
            if t - t0 >= run_s:
                a = np.array(rows)
                j = int(np.argmax(a[:, 1]))
                beyond = 100.0 * float(np.mean(np.abs(a[:, 2]) > 3.0 * a[:, 1]))
                return a[j, 1], a[j, 0], float(np.sqrt(np.mean(a[:, 2] ** 2))), beyond
            v = pipe.process(make_sample(t, b.gyro_rad_s[i], b.accel_m_s2[i], b.mag_ut[i], counter=k,
                                         flags=SampleFlags.NEW_DATA))
            if t - t0 >= 5.0:
                err = math.remainder(float(v.heading_true_rad) - _truth_yaw_rad(b.truth_q_wxyz[i]),
                                     2.0 * math.pi)
                rows.append((t - t0, math.degrees(float(v.sigma_rpy_rad[2])), math.degrees(err)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--offsets", type=int, nargs="+", default=[0, 3, 6, 12, 18, 24, 48, 96, 200])
    ap.add_argument("--run-s", type=float, default=120.0)
    args = ap.parse_args()
    peaks = []
    for off in args.offsets:
        peak, at, rms, beyond = one_start(args.seed, off, args.run_s)
        peaks.append(peak)
        print(f"seed {args.seed} start +{off:3d} samples: peak heading 1σ {peak:.3f}° at {at:5.1f} s, "
              f"heading RMS {rms:.2f}°, beyond 3σ {beyond:.2f} %", flush=True)
    print(f"seed {args.seed}: peaks {min(peaks):.3f}–{max(peaks):.3f}°, spread {max(peaks) - min(peaks):.3f}° over "
          f"{len(peaks)} starts")


if __name__ == "__main__":
    main()
