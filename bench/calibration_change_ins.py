"""ins through a magnetometer calibration change, with and without GNSS: its heading error and σ honesty against
the simulator's truth (docs/daemon.md "Calibration changes").

    .venv/bin/python bench/calibration_change_ins.py [--swap-s 15] [--gnss] [--no-widen]

Level turns with the simulator's vehicle iron, 200 Hz: until --swap-s the magnetometer is uncalibrated while the
calibration in force claims 0.5° (as after the iron moved), then the true iron model is swapped in as the daemon
does (daemon/calibration_swap.py: the heading change the new calibration makes, then the learned iron reset and
relearn_field_reference). --no-widen passes the change as unknown (NaN): the estimator's covariance is kept, as
before the widening. GNSS: 5 Hz, 1.5 m / 0.05 m/s (tests/ins_truth.py). Prints the heading RMS, the share
beyond 3σ of the published yaw σ and its median, in windows around the swap.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from ins_truth import DECLINATION, gnss_fixes, simulated_run, with_fixes_offered  # noqa: E402

from ahrsd.calibration.models import Calibration, MagModel  # noqa: E402
from ahrsd.core.sample import SampleFlags, make_sample  # noqa: E402
from ahrsd.daemon.calibration_heading_change import calibration_heading_change_rad  # noqa: E402
from ahrsd.estimator.ins import Ins  # noqa: E402
from ahrsd.simulation import open_stream  # noqa: E402

CLAIMED_SIGMA_RAD = math.radians(math.hypot(0.5, 0.2))   # heading_std_deg ⊕ offset_std_deg of the wrong calibration


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--swap-s", type=float, default=15.0)
    ap.add_argument("--gnss", action="store_true")
    ap.add_argument("--no-widen", action="store_true")
    args = ap.parse_args()
    swap = args.swap_s
    run = simulated_run("level-turns", swap + 60.0, rate_hz=200.0, seed=3)
    e = open_stream("level-turns", rate_hz=200.0, seed=3).errors
    old = Calibration.identity()
    new = Calibration.identity().with_sensor("mag", MagModel(e.hard_iron_ut, np.linalg.inv(e.soft_iron)))
    raw = run.block.mag_ut
    fixes = gnss_fixes(run.truth) if args.gnss else []
    ins = Ins(declination_rad=DECLINATION)
    ins.set_mag_calibration_sigma(CLAIMED_SIGMA_RAD)
    t = run.truth.t_s
    err, sigma = np.zeros(len(t)), np.zeros(len(t))
    last, swapped = None, False
    for k in with_fixes_offered(t, fixes, ins.update_gnss):
        if not swapped and t[k] >= swap and last is not None:
            swapped = True
            change = calibration_heading_change_rad(old, new, raw[k - 1], None, last.roll_rad, last.pitch_rad,
                                                    last.yaw_rad)
            print(f"calibration change at {t[k]:.1f} s moves the heading by {math.degrees(change):+.1f} deg")
            ins.set_mag_calibration_sigma(CLAIMED_SIGMA_RAD)
            ins.reset_learned_iron()
            ins.relearn_field_reference(math.nan if args.no_widen else change)
        mag = run.mag[k] if swapped else raw[k]
        last = ins.update(make_sample(t[k], run.gyro[k], run.accel[k], mag, flags=SampleFlags.NEW_DATA))
        w, x, y, z = run.truth.q_wxyz[k]
        truth_deg = math.degrees(Rotation.from_quat([x, y, z, w]).as_euler("ZYX")[0])
        err[k] = (math.degrees(last.heading_true_rad) - truth_deg + 180.0) % 360.0 - 180.0
        sigma[k] = math.degrees(last.sigma_rpy_rad[2])
    for a, b in [(swap - 10.0, swap), (swap, swap + 5.0), (swap + 5.0, swap + 20.0), (swap + 20.0, swap + 60.0)]:
        m = (t >= a) & (t < b)
        print(f"{a:5.0f}-{b:3.0f} s: heading RMS {np.sqrt(np.mean(err[m] ** 2)):6.2f} deg, beyond 3 sigma "
              f"{100.0 * np.mean(np.abs(err[m]) > 3.0 * sigma[m]):5.1f} %, median sigma {np.median(sigma[m]):6.2f} deg")


if __name__ == "__main__":
    main()
