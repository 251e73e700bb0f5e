"""A replay's attitude against the simulator's truth: RMS error, median published σ and the share of samples
beyond 3σ, for roll, pitch and true heading, from a chosen time on.

    python bench/replay_truth.py att.csv boat.csv [--from-s 1] [--every 10]

With `--every S` also the heading per S seconds from `--from-s` on: its mean and RMS error, the median published
σ and, for an aided replay (`--gnss`), the heading state the replay wrote most often in that stretch.

ATT.csv is what `ahrsd replay … --output` writes; REC.csv the simulated recording it replayed (`ahrsd record
--sim …`, whose `truth_q*` columns hold the true body-to-navigation quaternion, true north). Rows are matched by
their sample time `t_s`. The truth's Euler angles come from scipy (z-y-x, aerospace order), not from ahrsd's own
rotation code, so the figures are an independent check of what the replay's legend and σ columns claim.
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.spatial.transform import Rotation

ANGLES = (("roll", "roll_deg", "sigma_roll_deg"), ("pitch", "pitch_deg", "sigma_pitch_deg"),
          ("heading", "heading_true_deg", "sigma_yaw_deg"))


def read_csv(path: str) -> np.ndarray:
    return np.genfromtxt(path, delimiter=",", names=True, comments="#")


def wrap_deg(x: np.ndarray) -> np.ndarray:
    return (x + 180.0) % 360.0 - 180.0


def truth_angles_deg(rec: np.ndarray) -> dict[str, np.ndarray]:
    """Roll, pitch and true heading of the recording's truth quaternion (scalar-last for scipy)."""
    q = np.column_stack([rec["truth_qx"], rec["truth_qy"], rec["truth_qz"], rec["truth_qw"]])
    yaw, pitch, roll = Rotation.from_quat(q).as_euler("ZYX", degrees=True).T
    return {"roll": roll, "pitch": pitch, "heading": yaw % 360.0}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("attitude_csv")
    ap.add_argument("recording_csv")
    ap.add_argument("--from-s", type=float, default=0.0, help="leave out the samples before this time since the first")
    ap.add_argument("--every", type=float, default=0.0, help="also the heading per this many seconds (0: not)")
    args = ap.parse_args(argv)
    att, rec = read_csv(args.attitude_csv), read_csv(args.recording_csv)
    # each attitude row to the recording's row of the same sample time (the replay drops none, but say so if it did)
    # (the attitude CSV writes t_s to the µs: the nearest recording row, not the next)
    after = np.clip(np.searchsorted(rec["t_s"], att["t_s"]), 1, len(rec) - 1)
    nearer_before = np.abs(rec["t_s"][after - 1] - att["t_s"]) <= np.abs(rec["t_s"][after] - att["t_s"])
    idx = np.where(nearer_before, after - 1, after)
    matched = np.abs(rec["t_s"][idx] - att["t_s"]) < 1e-5
    if not np.all(matched):
        print(f"note: {np.count_nonzero(~matched)} attitude rows have no recording row at their time: left out")
    att, rec = att[matched], rec[idx[matched]]
    truth = truth_angles_deg(rec)
    keep = att["t_s"] - att["t_s"][0] >= args.from_s
    print(f"{args.attitude_csv} against {args.recording_csv}'s truth, {np.count_nonzero(keep)} samples from "
          f"{args.from_s:g} s")
    for name, column, sigma_column in ANGLES:
        err = wrap_deg(att[column] - truth[name])[keep]
        sigma = att[sigma_column][keep]
        print(f"  {name:<8} RMS {np.sqrt(np.mean(err**2)):6.2f}°   median σ {np.median(sigma):6.2f}°   "
              f"beyond 3σ {100.0 * np.mean(np.abs(err) > 3.0 * sigma):5.2f} %")
    if args.every > 0.0:
        _heading_every(att[keep], truth["heading"][keep], args.every)
    return 0


def _heading_every(att: np.ndarray, truth_deg: np.ndarray, every_s: float) -> None:
    """The heading's error per `every_s` seconds: mean, RMS, median σ, and the most frequent heading state."""
    from ahrsd.core.estimate import HeadingState

    err = wrap_deg(att["heading_true_deg"] - truth_deg)
    t = att["t_s"]
    states = att["heading_state"] if "heading_state" in (att.dtype.names or ()) else None
    print(f"  heading per {every_s:g} s: from s | mean error ° | RMS ° | median σ ° | heading state")
    for start in np.arange(t[0], t[-1], every_s):
        k = (t >= start) & (t < start + every_s)
        if not np.any(k):
            continue
        state = ""
        if states is not None:
            values, counts = np.unique(states[k].astype(int), return_counts=True)
            state = HeadingState(int(values[np.argmax(counts)])).name.lower()
        print(f"  {start:7.1f} | {np.mean(err[k]):+6.2f} | {np.sqrt(np.mean(err[k] ** 2)):5.2f} | "
              f"{np.median(att['sigma_yaw_deg'][k]):5.2f} | {state}")


if __name__ == "__main__":
    raise SystemExit(main())
