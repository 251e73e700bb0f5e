"""Where ins's heading error on level turns comes from, split with the simulator's truth (docs/estimator.md
"Known limits: ins on level turns").

    .venv/bin/python bench/ins_level_turns_split.py [--seed 3] [--seconds 75] [--swap-s 15] [--gnss]
        [--accel-without-turn] [--gyro-without-bias] [--no-magnetometer] [--trace]

The setting of bench/calibration_change_ins.py (level turns, 200 Hz, the calibration in force claims 0.54°):
with --swap-s the magnetometer is uncalibrated until then and the true iron model is swapped in as the daemon
does; without it the magnetometer is calibrated from the start. Counterfactuals from the truth:
--accel-without-turn feeds the accelerometer with the true linear (centripetal, heave) acceleration removed, so
it measures gravity alone; --gyro-without-bias removes the true gyro bias; --no-magnetometer runs ins without it (mag_enabled False). Per window it prints the roll, pitch
and heading RMS beside their published σ (median, share beyond 3σ) and the heading error a perfect magnetometer
would make at the estimate's tilt (true body field, tilt-compensated with the estimated roll and pitch).
--trace prints every 2 s (every 0.5 s in the first 4 s) the heading error, σ, heading state, ins's vertical gyro bias against the truth and,
with GNSS, the GNSS yaw's (gsf_yaw.py) error and σ.
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

CLAIMED_SIGMA_RAD = math.radians(math.hypot(0.5, 0.2))   # as bench/calibration_change_ins.py


def _wrap(a):
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def _tilt_compensated_heading(field_body, roll, pitch):
    """Magnetic heading of body-frame fields levelled with the given roll and pitch (ZYX Euler)."""
    level = Rotation.from_euler("YX", np.column_stack([pitch, roll])).apply(field_body)
    return -np.arctan2(level[:, 1], level[:, 0])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=75.0)
    ap.add_argument("--swap-s", type=float, default=None)
    ap.add_argument("--gnss", action="store_true")
    ap.add_argument("--accel-without-turn", action="store_true")
    ap.add_argument("--gyro-without-bias", action="store_true")
    ap.add_argument("--no-magnetometer", action="store_true")
    ap.add_argument("--trace", action="store_true")
    args = ap.parse_args()
    run = simulated_run("level-turns", args.seconds, rate_hz=200.0, seed=args.seed)
    stream = open_stream("level-turns", rate_hz=200.0, seed=args.seed)
    e = stream.errors
    t = run.truth.t_s
    q = run.truth.q_wxyz
    truth_rot = Rotation.from_quat(np.column_stack([q[:, 1], q[:, 2], q[:, 3], q[:, 0]]))   # body → true NED
    accel = run.accel
    if args.accel_without_turn:
        accel = accel - truth_rot.inv().apply(stream.scenario.accel_ned_m_s2(t))
    gyro = run.gyro - run.block.truth_gyro_bias_rad_s if args.gyro_without_bias else run.gyro
    old = Calibration.identity()
    new = Calibration.identity().with_sensor("mag", MagModel(e.hard_iron_ut, np.linalg.inv(e.soft_iron)))
    fixes = gnss_fixes(run.truth) if args.gnss else []
    ins = Ins(declination_rad=DECLINATION, mag_enabled=not args.no_magnetometer)
    ins.set_mag_calibration_sigma(CLAIMED_SIGMA_RAD)
    est = np.zeros((len(t), 3))
    sigma = np.zeros((len(t), 3))
    last, swapped = None, args.swap_s is None
    for k in with_fixes_offered(t, fixes, ins.update_gnss):
        if not swapped and t[k] >= args.swap_s and last is not None:
            swapped = True
            change = calibration_heading_change_rad(old, new, run.block.mag_ut[k - 1], None, last.roll_rad,
                                                    last.pitch_rad, last.yaw_rad)
            print(f"calibration change at {t[k]:.1f} s moves the heading by {math.degrees(change):+.1f} deg")
            ins.set_mag_calibration_sigma(CLAIMED_SIGMA_RAD)
            ins.reset_learned_iron()
            ins.relearn_field_reference(change)
        mag = run.mag[k] if swapped else run.block.mag_ut[k]
        last = ins.update(make_sample(t[k], gyro[k], accel[k], mag, flags=SampleFlags.NEW_DATA))
        est[k] = (last.roll_rad, last.pitch_rad, last.heading_true_rad)
        sigma[k] = last.sigma_rpy_rad
        if args.trace and (k % 400 == 0 or (t[k] < 4.0 and k % 100 == 0)):
            truth_yaw = truth_rot[k].as_euler("ZYX")[0]
            line = (f"{t[k]:5.1f} s heading error {math.degrees(_wrap(last.heading_true_rad - truth_yaw)):+7.2f} "
                    f"σ {math.degrees(last.sigma_rpy_rad[2]):6.2f} {last.heading_state.name:12s} vertical gyro bias "
                    f"{math.degrees(last.gyro_bias_rad_s[2]):+6.3f} (true "
                    f"{math.degrees(run.block.truth_gyro_bias_rad_s[k, 2]):+6.3f}) deg/s")
            if last.integrity is not None:
                i = last.integrity
                line += (f" | GNSS yaw error {math.degrees(_wrap(i.gsf_yaw_rad - truth_yaw)):+7.1f} "
                         f"σ {math.degrees(i.gsf_sigma_rad):5.1f} valid {int(i.gsf_valid)}")
            print(line)
    ypr = truth_rot.as_euler("ZYX")
    truth = np.column_stack([ypr[:, 2], ypr[:, 1], ypr[:, 0]])
    err = np.degrees(_wrap(est - truth))
    sig = np.degrees(sigma)
    field_body = run.block.truth_mag_ut
    perfect = _tilt_compensated_heading(field_body, truth[:, 0], truth[:, 1])
    tilt_induced = np.degrees(_wrap(_tilt_compensated_heading(field_body, est[:, 0], est[:, 1]) - perfect))
    # the windows of bench/calibration_change_ins.py: 20 s after the change to the end; without one, 20–35 s
    # (after the start) and 35 s to the end
    windows = [(20.0, 35.0), (35.0, args.seconds)] if args.swap_s is None else [(args.swap_s + 20.0, args.seconds)]
    for a, b in windows:
        m = (t >= a) & (t < b)
        if not m.any():
            continue
        parts = []
        for i, name in enumerate(("roll", "pitch", "heading")):
            parts.append(f"{name} {np.sqrt(np.mean(err[m, i] ** 2)):5.2f} σ {np.median(sig[m, i]):5.2f} "
                         f"beyond {100.0 * np.mean(np.abs(err[m, i]) > 3.0 * sig[m, i]):5.1f} %")
        print(f"{a:5.0f}-{b:3.0f} s RMS deg: " + " | ".join(parts)
              + f" | heading error of a perfect magnetometer at the estimated tilt "
                f"{np.sqrt(np.mean(tilt_induced[m] ** 2)):5.2f}")


if __name__ == "__main__":
    main()
