"""A VISION_POSITION_ESTIMATE gap during a heading slew (issue 28 "the daemon says what it knows"): while the
heading is UNKNOWN no VPE is sent, and the first one after the gap continues from the last one sent, turned by
the vehicle's rotation over the gap (integrated at each withheld tick), then slews on: no step above the slew
rate × one VPE interval in the error the autopilot sees. The vehicle's motion is the simulator's truth."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
from scipy.spatial.transform import Rotation

from ahrsd.core.estimate import HeadingState
from ahrsd.daemon.heading_resets import HeadingResets
from ahrsd.core.angles import yaw_rate_ned_rad_s
from ahrsd.daemon.heading_slew import MAX_STEP_INTERVAL_S, HeadingSlew
from ahrsd.simulation import open_stream

VPE_HZ = 30.0
RATE_DEG_S = 2.0
CHANGE_DEG = 40.0


def _truth_ticks(seconds: float):
    """(t, true heading deg, body rates rad/s, roll, pitch) at the VPE ticks, from the simulator's level turns."""
    stream = open_stream("level-turns", seed=3)
    rows, next_t = [], 0.0
    while next_t < seconds:
        b = stream.next_block(4096)
        for i in np.flatnonzero(b.t_s >= next_t):
            t = float(b.t_s[i])
            if t < next_t:
                continue
            w, x, y, z = b.truth_q_wxyz[i]
            yaw, pitch, roll = Rotation.from_quat([x, y, z, w]).as_euler("ZYX")      # body → NED
            rows.append((t, math.degrees(yaw), b.truth_gyro_rad_s[i].copy(), roll, pitch))
            next_t += 1.0 / VPE_HZ
            if next_t >= seconds:
                break
    return rows


def _run(gap_s: tuple[float, float], use_withheld: bool = True):
    """The estimator's heading is the truth, plus CHANGE_DEG from 10 s (a calibration change swapped in then);
    the heading is UNKNOWN (VPE withheld) during `gap_s`. Returns (t, published − truth in deg) of the VPEs sent."""
    resets = HeadingResets(HeadingSlew(max_rate_deg_s=RATE_DEG_S))
    sent = []
    started = False
    for t, heading_deg, rate, roll, pitch in _truth_ticks(40.0):
        if not started and t >= 10.0:
            resets.slew.start_transition()
            started = True
        est = SimpleNamespace(t_s=t, heading_true_rad=math.radians(heading_deg + (CHANGE_DEG if started else 0.0)),
                              rate_body_rad_s=rate, roll_rad=roll, pitch_rad=pitch,
                              sigma_rpy_rad=np.radians([0.2, 0.2, 0.5]), heading_state=HeadingState.MAGNETOMETER)
        if gap_s[0] <= t < gap_s[1]:
            if use_withheld:
                resets.withheld(est)
            continue
        yaw, _counter, _sigma = resets.autopilot_yaw(est)
        sent.append((t, (math.degrees(yaw) - heading_deg + 180.0) % 360.0 - 180.0))
    return np.array(sent)


def test_the_first_vpe_after_a_gap_continues_the_slew_without_a_step():
    t, err = _run((14.0, 19.0)).T
    steps = np.abs(np.diff(err))
    one_interval = RATE_DEG_S / VPE_HZ
    i = np.searchsorted(t, 19.0)           # the first VPE after the gap
    print(f"\nslew error before the gap {err[i - 1]:.2f} deg, after {err[i]:.2f} deg (slew step {one_interval:.3f} "
          f"deg per VPE); largest step {steps.max():.3f} deg")
    assert CHANGE_DEG - err[i - 1] > 20.0                       # the slew was running, far from done
    # the turn over the gap is integrated at 30 Hz (rectangles): its error is well below a VPE's slew step
    assert abs(err[i] - err[i - 1]) <= one_interval * 1.5, (err[i - 1], err[i])
    assert steps.max() <= one_interval * 1.5
    assert abs(err[-1] - CHANGE_DEG) < 0.1                      # and it still ends at the estimator's heading


def test_without_an_estimate_to_follow_the_first_step_after_a_gap_is_bounded():
    """No estimate during the gap (nothing withheld to follow: the turn is extrapolated from the yaw rate when the
    estimates come back): the slew still moves at most rate × MAX_STEP_INTERVAL_S towards the estimator at once,
    not rate × gap (10° here). The published change is the extrapolated turn plus that step."""
    t, err = _run((14.0, 19.0), use_withheld=False).T
    ticks = _truth_ticks(20.0)
    i = np.searchsorted(t, 19.0)
    before = max(k for k, row in enumerate(ticks) if row[0] < 14.0)
    after = min(k for k, row in enumerate(ticks) if row[0] >= 19.0)
    (t0, h0, *_), (t1, h1, rate, roll, pitch) = ticks[before], ticks[after]
    extrapolated_deg = math.degrees(yaw_rate_ned_rad_s(rate, roll, pitch)) * (t1 - t0)
    true_turn_deg = (h1 - h0 + 180.0) % 360.0 - 180.0
    step_deg = (err[i] - err[i - 1]) - (extrapolated_deg - true_turn_deg)
    assert abs(step_deg - RATE_DEG_S * MAX_STEP_INTERVAL_S) < 1e-6, step_deg
