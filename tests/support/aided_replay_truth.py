"""`ahrsd replay --gnss` of a recording (written with the simulator's truth columns, as `ahrsd record --sim`
writes them) against that truth: for the tests of the published heading and its σ on a whole boat run."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ahrsd.cli.main import main
from ahrsd.drivers.recording import read_recording


@dataclass
class AidedReplayHeading:
    t_s: np.ndarray              # from the recording's first sample
    yaw_error_deg: np.ndarray    # the replay's yaw − the simulator's, wrapped to ±180°
    sigma_yaw_deg: np.ndarray    # the replay's published yaw σ
    flags: np.ndarray            # the replay's flags column (EstimateFlags)


def aided_replay_heading(rec: Path, out: Path) -> AidedReplayHeading:
    """Replay `rec` with REC.gnss.csv beside it (the aided estimator, ins) into `out`, which must succeed (the
    CLI's stderr is in the caller's capsys)."""
    code = main(["replay", str(rec), "--gnss", str(rec.with_suffix(".gnss.csv")), "-o", str(out), "--quiet"])
    assert code == 0, f"ahrsd replay failed ({code})"
    cols = open(out).readline().strip().split(",")
    # only the columns read: loadtxt converts a quarter as many fields (the output has ~26 columns a sample)
    read = ["t_s", "yaw_deg", "sigma_yaw_deg", "flags"]
    assert cols[0] == "t_s", cols[0]
    data = np.loadtxt(out, delimiter=",", skiprows=1, usecols=[cols.index(c) for c in read], ndmin=2)
    cols = read
    r = read_recording(rec)     # the simulator's truth, written beside the samples: not the filter's
    q = np.column_stack([r.extra[c] for c in ("truth_qx", "truth_qy", "truth_qz", "truth_qw")])
    truth_yaw = Rotation.from_quat(q).as_euler("ZYX", degrees=True)[:, 0]
    return AidedReplayHeading(t_s=data[:, 0] - r.t_s[0],
                              yaw_error_deg=(data[:, cols.index("yaw_deg")] - truth_yaw + 180.0) % 360.0 - 180.0,
                              sigma_yaw_deg=data[:, cols.index("sigma_yaw_deg")],
                              flags=data[:, cols.index("flags")].astype(np.int64))
