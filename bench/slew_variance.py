"""What an autopilot does with the VISION_POSITION_ESTIMATE yaw variance while a heading change is slewed in:
the σ rule behind docs/daemon.md "Calibration changes" / "Restarts" (daemon/heading_slew.py published_sigma_rad).

    .venv/bin/python bench/slew_variance.py

The published yaw starts on the heading the autopilot holds (it fused it for 2 min, in flight: gated) and moves
to a heading D away at r °/s; the offset still to come is d. The yaw's 1σ sent with it is, per rule:
  estimator's σ      — the estimator's own (0.5° here): not honest, the VPE is d off;
  hypot(σ, d)        — d counted as a 1σ error (ins's published heading today, estimator/published_heading.py);
  σ + d/3            — 3σ covers d and the estimator's own 3σ;
  sent               — σ + d/3 with the daemon's own slew (daemon.heading_slew.HeadingSlew at r °/s, which holds
                       the rate to 2 °/s while that σ is above EKF3's 5° floor).
Each line: when the yaw sent reached the new heading, VPEs the fake autopilot rejected, its largest yaw test ratio (> 1 rejects), its overshoot past the new
heading and when it was last more than 1° off it (the fakes of tests/support/fake_autopilot_yaw.py: the
sources' R, floors and gates; ArduPilot's angErr by the current rule, "sqrt", and 4.6's, "cbrt").
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from support.fake_autopilot_yaw import FakeEkf2, FakeEkf3, warm_up  # noqa: E402

from ahrsd.daemon.heading_slew import HeadingSlew  # noqa: E402

VPE_HZ = 30.0
SIGMA_DEG = 0.5
TAIL_S = 120.0
RULES = {
    "estimator's σ": lambda s, d: s,
    "hypot(σ, d)": lambda s, d: math.hypot(s, d),
    "σ + d/3": lambda s, d: s + d / 3.0,
    "sent": None,
}
AUTOPILOTS = {
    "EKF3 VISO_YAW_M_NSE 0.05": lambda: FakeEkf3(0.05),
    "EKF3 0.05, 4.6 angErr": lambda: FakeEkf3(0.05, ang_err_rule="cbrt"),
    "EKF3 VISO_YAW_M_NSE 0.2": lambda: FakeEkf3(0.2),
    "EKF2 EKF2_EVA_NOISE 0.05": lambda: FakeEkf2(0.05),
}
CASES = ((10.0, 3.0), (30.0, 3.0), (40.0, 3.0), (60.0, 3.0), (90.0, 3.0), (170.0, 3.0),     # restarts (restart_slew_deg_s)
         (30.0, 2.0), (90.0, 2.0), (170.0, 2.0))                                # calibration changes, (D deg, r deg/s)


def slew(make, step_deg: float, rate_deg_s: float, rule) -> tuple[int, float, float, float]:
    ap = make()
    s = math.radians(SIGMA_DEG)
    warm_up(ap, 0.0, 120.0, -120.0, angle_vars=(s * s,) * 3)
    step, rate = math.radians(step_deg), math.radians(rate_deg_s)
    daemon_slew = HeadingSlew(max_rate_deg_s=rate_deg_s, min_duration_s=0.0)
    daemon_slew.start_from(0.0)
    yaws, t, t_end = [], 0.0, None
    while t_end is None or t < t_end + TAIL_S:
        if rule is None:                                  # what the daemon sends
            published = daemon_slew.update(t, step, 0.0, s)
            sigma = daemon_slew.published_sigma_rad(s)
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


def main() -> None:
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
