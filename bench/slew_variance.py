"""What an autopilot does with the VISION_POSITION_ESTIMATE yaw variance while a heading change is slewed in:
the σ rule behind docs/daemon.md "Calibration changes" / "Restarts" (daemon/heading_slew.py published_sigma_rad).

    .venv/bin/python bench/slew_variance.py

The published yaw starts on the heading the autopilot holds (it fused it for 2 min, in flight: gated) and moves
to a heading D away at r °/s; the offset still to come is d. The yaw's 1σ sent with it is, per rule:
  estimator's σ      — the estimator's own (0.5° here): not honest, the VPE is d off;
  hypot(σ, d)        — d counted as a 1σ error (ins's published heading before estimator/slewed_yaw.py);
  σ + d/3            — 3σ covers d and the estimator's own 3σ;
  sent               — σ + d/3 with the daemon's own slew (daemon.heading_slew.HeadingSlew at r °/s, which holds
                       the rate to 2 °/s while that σ is above EKF3's 5° floor);
  ins published      — ins's published heading (estimator.published_heading.PublishedHeading at r °/s) after the
                       filter's yaw was reset by D (a reset to the GNSS yaw), with its σ: the same rule
                       (estimator/slewed_yaw.py) as "sent". Before that rule ins published hypot(σ, d) at 2 °/s.
With --ins-boat SEED…: ins itself on the simulated boat (`ins_reset_slew_out`: its yaw 30–170° off the truth and
published so, then reset to the truth; the published yaw's error and σ against the simulator's truth go to a fake
EKF3), with ins's σ rule and with hypot(σ, offset) (its rule before estimator/slewed_yaw.py):

    .venv/bin/python bench/slew_variance.py --ins-boat 5 11 14

Each line: when the yaw sent reached the new heading, VPEs the fake autopilot rejected, its largest yaw test ratio (> 1 rejects), its overshoot past the new
heading and when it was last more than 1° off it (the fakes of tests/support/fake_autopilot_yaw.py: the
sources' R, floors and gates; ArduPilot's angErr by the current rule, "sqrt", and 4.6's, "cbrt").
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from support.fake_autopilot_yaw import FakeEkf2, FakeEkf3, warm_up  # noqa: E402

from ahrsd.daemon.heading_slew import HeadingSlew  # noqa: E402
from ahrsd.estimator.published_heading import PublishedHeading  # noqa: E402
from ahrsd.estimator.slewed_yaw import YawSlew  # noqa: E402

VPE_HZ = 30.0
SIGMA_DEG = 0.5
TAIL_S = 120.0
RULES = {
    "estimator's σ": lambda s, d: s,
    "hypot(σ, d)": lambda s, d: math.hypot(s, d),
    "σ + d/3": lambda s, d: s + d / 3.0,
    "sent": "daemon",
    "ins published": "ins",
}
AUTOPILOTS = {
    "EKF3 VISO_YAW_M_NSE 0.05": lambda: FakeEkf3(0.05),
    "EKF3 0.05, 4.6 angErr": lambda: FakeEkf3(0.05, ang_err_rule="cbrt"),
    "EKF3 VISO_YAW_M_NSE 0.2": lambda: FakeEkf3(0.2),
    "EKF2 EKF2_EVA_NOISE 0.05": lambda: FakeEkf2(0.05),
}
CASES = ((10.0, 3.0), (30.0, 3.0), (40.0, 3.0), (60.0, 3.0), (90.0, 3.0), (170.0, 3.0),     # restarts (restart_slew_deg_s)
         (30.0, 2.0), (60.0, 2.0), (90.0, 2.0), (120.0, 2.0), (170.0, 2.0))     # calibration changes, ins's
# yaw resets (its rate 2 °/s; the 3 °/s cases show its cap), (D deg, r deg/s)


def slew(make, step_deg: float, rate_deg_s: float, rule) -> tuple[int, float, float, float]:
    ap = make()
    s = math.radians(SIGMA_DEG)
    warm_up(ap, 0.0, 120.0, -120.0, angle_vars=(s * s,) * 3)
    step, rate = math.radians(step_deg), math.radians(rate_deg_s)
    daemon_slew = HeadingSlew(max_rate_deg_s=rate_deg_s, min_duration_s=0.0)
    daemon_slew.start_from(0.0)
    ins_published = PublishedHeading(rate)
    ins_published.update(-1.0 / VPE_HZ, 0.0, 0.0, 0.0, (0.0, 0.0, 0.0), s)   # the filter's yaw before the reset
    yaws, t, t_end = [], 0.0, None
    while t_end is None or t < t_end + TAIL_S:
        if rule == "daemon":                              # what the daemon sends
            published = daemon_slew.update(t, step, 0.0, s)
            sigma = daemon_slew.published_sigma_rad(s)
        elif rule == "ins":                               # what ins publishes after its yaw was reset to `step`
            published = step + ins_published.update(t, step, 0.0, 0.0, (0.0, 0.0, 0.0), s)
            sigma = ins_published.published_sigma(s)
        else:
            published = min(step, rate * t)
            sigma = rule(s, step - published)
        ap.feed(t, published, 0, (s * s, s * s, sigma * sigma))
        yaws.append((t, math.remainder(math.degrees(ap.yaw) - step_deg, 360.0)))
        if t_end is None and abs(published - step) < 1e-9:
            t_end = t
        t += 1.0 / VPE_HZ
    overshoot = max(0.0, max(e for _, e in yaws))
    off = [t for t, e in yaws if abs(e) > 1.0]
    return ap.rejected, getattr(ap, "max_test_ratio", math.nan), overshoot, off[-1] if off else 0.0, t_end


class HypotYawSlew(YawSlew):
    """The slew with the σ ins published before estimator/slewed_yaw.py: the offset counted as a 1σ error."""

    @staticmethod
    def sigma_rad(sigma_rad: float, offset_rad: float) -> float:
        return math.hypot(sigma_rad, offset_rad)


def ins_reset_slew_out(run, rate_deg_s: float, wrong_deg: float = 100.0, slew=YawSlew):
    """ins on the boat, its yaw `wrong_deg` off the truth from 40 s with σ 0.5° (a wrong calibration that claimed
    to be good: no fix or magnetometer sample for 10 s, so nothing pulls it back), and that wrong yaw published
    (the published heading restarted on it) to a fake ArduPilot EKF3 that has fused it for 2 min; at 50 s the yaw
    is reset to the simulator's true yaw with σ 0.5° (a reset to a right GNSS yaw) and the published yaw slews out
    the offset at `rate_deg_s`. The fake gets the published yaw's error against the truth (the vehicle's own
    rotation is common to both EKFs: tests/support/fake_autopilot_yaw.py is a vehicle at rest) with the published
    σ at 30 Hz. Returns the share of 30 Hz messages beyond the published 3σ from 50 s, the fake, and how often
    ins's own heading checks reset its yaw after that (beyond the planted two; their GNSS yaw bank went through the
    10 s without fixes too, so it can be wrong then: the published yaw then follows a wrong filter). slew: the
    YawSlew class ins's published heading slews with (HypotYawSlew: the σ rule before)."""
    from scipy.spatial.transform import Rotation

    from ahrsd.core.gnss import GnssFix
    from ahrsd.estimator.ins import Ins
    from ahrsd.simulation import in_arrival_order

    def yaw(q_wxyz):
        return Rotation.from_quat(np.roll(q_wxyz, -1)).as_euler("ZYX")[0]

    est = Ins(declination_rad=run.declination_rad, mag_calibration_sigma_rad=run.mag_calibration_sigma_rad,
              published_yaw_slew_rad_s=math.radians(rate_deg_s))
    est._published._slew = slew(est._published.max_rate_rad_s)       # the rule compared
    k_wrong, k_right = np.searchsorted(run.t_s, [40.0, 50.0])
    truth_yaw = Rotation.from_quat(np.roll(run.truth_q_wxyz, -1, axis=1)).as_euler("ZYX")[:, 0]   # one call, not n
    fixes = [f for f in run.fixes if not 40.0 <= f.t_s < 50.0]
    ekf3 = FakeEkf3(0.05)
    n = len(run.t_s)
    k, t_next, beyond, sent = -1, 0.0, 0, 0
    for item in in_arrival_order(_samples_without_mag(run, k_wrong, k_right), fixes):
        if isinstance(item, GnssFix):
            if k == n - 1:
                break           # it arrived after the last sample: not offered
            est.update_gnss(item)
            continue
        k += 1
        truth = float(truth_yaw[k])
        if k == k_wrong:
            est._heading.reset_yaw(truth + math.radians(wrong_deg) - yaw(est.true_attitude_q_wxyz()), math.radians(0.5) ** 2)
            est._published.reset()      # the wrong yaw is what was published all along
        if k == k_right:
            est._heading.reset_yaw(truth - yaw(est.true_attitude_q_wxyz()), math.radians(0.5) ** 2)
        e = est.update(item)
        if k < k_wrong or run.t_s[k] < t_next:
            continue
        t_next = run.t_s[k] + 1.0 / 30.0
        err = math.remainder(e.heading_true_rad - truth, 2.0 * math.pi)
        s = e.sigma_rpy_rad
        if k == k_wrong:
            warm_up(ekf3, err, 120.0, run.t_s[k] - 120.0, angle_vars=(s[0] ** 2, s[1] ** 2, s[2] ** 2))
        ekf3.feed(run.t_s[k], err, 0, (s[0] ** 2, s[1] ** 2, s[2] ** 2))
        if k >= k_right:
            sent += 1
            beyond += abs(err) > 3.0 * s[2]
    return beyond / sent, ekf3, est.yaw_resets - 2


def _samples_without_mag(run, k_from: int, k_to: int):
    """The run's samples, the magnetometer's left out (NaN) from sample k_from to before k_to."""
    from ahrsd.core.sample import SampleFlags, make_sample

    return (make_sample(run.t_s[k], run.gyro_rad_s[k], run.accel_m_s2[k],
                        np.full(3, np.nan) if k_from <= k < k_to else run.mag_ut[k],
                        flags=SampleFlags.NEW_DATA) for k in range(len(run.t_s)))


def ins_on_the_boat(seeds: list[int]) -> None:
    from bench.vehicle_accuracy import simulate_vehicle

    rules = {"σ + |offset|/3": YawSlew, "hypot (before)": HypotYawSlew}
    print("ins on the boat, yaw reset to the truth at 50 s after 10 s published D off it, slewed out at 2 °/s; "
          "fake EKF3 VISO_YAW_M_NSE 0.05")
    for seed in seeds:
        run = simulate_vehicle("boat", 150.0, seed, None)
        for wrong_deg in (30.0, 60.0, 90.0, 120.0, 170.0):
            for name, slew in rules.items():
                beyond, ekf3, own_resets = ins_reset_slew_out(run, 2.0, wrong_deg, slew)
                print(f"  seed {seed:3d}  D {wrong_deg:5.0f}°  {name:15s} beyond 3σ {100 * beyond:5.2f} %  "
                      f"rejected {ekf3.rejected:5d}  test ratio {ekf3.max_test_ratio:6.2f}  "
                      f"EKF3 yaw error at 150 s {math.degrees(ekf3.yaw):7.2f}°  ins's own resets after "
                      f"{own_resets}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ins-boat", type=int, nargs="+", metavar="SEED",
                    help="instead: ins's own yaw reset slew-out on the simulated boat (these seeds)")
    args = ap.parse_args()
    if args.ins_boat:
        ins_on_the_boat(args.ins_boat)
        return
    for step_deg, rate_deg_s in CASES:
        print(f"\n{step_deg:g}° slewed in at {rate_deg_s:g} °/s")
        for ap_name, make in AUTOPILOTS.items():
            for rule_name, rule in RULES.items():
                rejected, ratio, overshoot, settled, t_end = slew(make, step_deg, rate_deg_s, rule)
                ratio_text = f"{ratio:5.2f}" if math.isfinite(ratio) else "    -"
                print(f"  {ap_name:25s} {rule_name:13s} yaw there at {t_end:5.1f} s  rejected {rejected:5d}  "
                      f"test ratio {ratio_text}  overshoot {overshoot:4.1f}°  within 1° after {settled:5.1f} s")


if __name__ == "__main__":
    main()
