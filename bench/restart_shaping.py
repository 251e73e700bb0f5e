"""Can a shaped yaw profile land an autopilot's EKF on a new heading without overshoot? The bound behind
docs/daemon.md "Restarts".

    .venv/bin/python bench/restart_shaping.py            # EKF3 VISO_YAW_M_NSE=0.05, T = 10, 20, 30, 35 s

The fake EKFs of tests/support/fake_autopilot_yaw.py (yaw + z gyro bias, the sources' noise and gates) are
linear while every sample is fused, with gains that no longer change after 2 min of warm-up. So the
autopilot's yaw is an affine function of the yaw sequence we send, and a linear program (scipy HiGHS) finds
the sequence that minimises the largest innovation |EKF yaw − ours| subject to: the EKF's yaw within ±1° of
the new heading from T on (for H = 40 s more, our yaw then held on it). If that smallest largest innovation
exceeds the gate (3 · 5° = 15° for EKF3 with VISO_YAW_M_NSE ≤ 0.087), no profile meets "settled by T".
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import linprog

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from support.fake_autopilot_yaw import FakeEkf3, warm_up  # noqa: E402

VPE_HZ = 30.0
STEP_DEG = 30.0
BAND_DEG = 1.0
HOLD_AFTER_S = 40.0


def steady_gains(make, n: int):
    """The (yaw, bias) Kalman gains and the number of 12 ms predictions before each of n VPEs."""
    ap = make()
    t0 = warm_up(ap, 0.0, 120.0)
    f, gains, steps = ap.filter, [], []
    fuse = f.fuse

    def recording_fuse(innov, r, clip_rad=math.inf):
        s = f.p[0][0] + r
        gains.append((f.p[0][0] / s, f.p[0][1] / s))
        fuse(innov, r, clip_rad)
    f.fuse = recording_fuse
    for k in range(n):
        before = f.t_s
        ap.feed(t0 + k / VPE_HZ, 0.0, 0)
        steps.append(round((f.t_s - before) / f.dt_s))
    return np.array(gains), np.array(steps), f.dt_s


def smallest_largest_innovation_deg(make, settle_s: float) -> float:
    n_free, n = int(settle_s * VPE_HZ), int((settle_s + HOLD_AFTER_S) * VPE_HZ)
    gains, steps, dt = steady_gains(make, n)
    # x = (yaw, bias) as linear maps of the n sent yaws (deg); prior = before fusing sample k
    prior, post = np.zeros((n, 2, n)), np.zeros((n, 2, n))
    x = np.zeros((2, n))
    for k in range(n):
        x = np.array([[1.0, -dt * steps[k]], [0.0, 1.0]]) @ x
        prior[k] = x
        innov = x[0].copy()
        innov[k] -= 1.0
        x = x - np.outer(gains[k], innov)
        post[k] = x
    # unknowns: the first n_free sent yaws and E; from n_free on we send the new heading
    rows, rhs = [], []
    for k in range(n):
        r = prior[k, 0].copy()
        r[k] -= 1.0
        c, c0 = r[:n_free], r[n_free:].sum() * STEP_DEG
        rows += [np.r_[c, -1.0], np.r_[-c, -1.0]]
        rhs += [-c0, c0]
    for k in range(n_free, n):
        c, c0 = post[k, 0, :n_free], post[k, 0, n_free:].sum() * STEP_DEG
        rows += [np.r_[c, 0.0], np.r_[-c, 0.0]]
        rhs += [STEP_DEG + BAND_DEG - c0, -(STEP_DEG - BAND_DEG) + c0]
    cost = np.zeros(n_free + 1)
    cost[-1] = 1.0
    res = linprog(cost, A_ub=np.array(rows), b_ub=np.array(rhs), bounds=[(None, None)] * n_free + [(0, None)],
                  method="highs")
    assert res.status == 0, res.message
    return float(res.fun)


def main() -> None:
    make = lambda: FakeEkf3(0.05)  # noqa: E731
    gate = FakeEkf3(0.05).gate * 5.0
    print(f"EKF3 VISO_YAW_M_NSE=0.05, {STEP_DEG:g}° step, within ±{BAND_DEG:g}° from T on; gate {gate:.0f}°")
    print("T (s) | smallest possible largest innovation (deg) | inside the gate")
    for settle_s in (10.0, 20.0, 30.0, 35.0):
        e = smallest_largest_innovation_deg(make, settle_s)
        print(f"{settle_s:5.0f} | {e:8.1f} | {'yes' if e <= gate else 'no'}")


if __name__ == "__main__":
    main()
