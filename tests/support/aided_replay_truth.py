"""`ahrsd replay --gnss` of a recording (written with the simulator's truth columns, as `ahrsd record --sim`
writes them) against that truth: for the tests of the published heading and its σ on a whole boat run.

`aided_replay_heading` runs the command and reads its output; `aided_heading_in_process` runs the same estimator,
set up by the command's own functions, on the same samples and fixes in this process, and builds the estimate at
every `every`-th sample only (the others stepped: estimator/estimate_view.py, building none changes none), with
no output file: tests/test_aided_replay_in_process.py checks it against the command's output."""

from __future__ import annotations

import argparse
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


def _truth_yaw_deg(rec: Path, index=slice(None)) -> tuple[np.ndarray, np.ndarray]:
    """The recording's times and the simulator's yaw (deg), written beside the samples: not the filter's."""
    r = read_recording(rec)
    q = np.column_stack([r.extra[c][index] for c in ("truth_qx", "truth_qy", "truth_qz", "truth_qw")])
    return r.t_s, Rotation.from_quat(q).as_euler("ZYX", degrees=True)[:, 0]


def _heading(t_s, t0_s, yaw_deg, truth_yaw_deg, sigma_yaw_deg, flags) -> AidedReplayHeading:
    return AidedReplayHeading(t_s=t_s - t0_s, yaw_error_deg=(yaw_deg - truth_yaw_deg + 180.0) % 360.0 - 180.0,
                              sigma_yaw_deg=sigma_yaw_deg, flags=flags.astype(np.int64))


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
    t_rec, truth_yaw = _truth_yaw_deg(rec)
    return _heading(data[:, 0], t_rec[0], data[:, 1], truth_yaw, data[:, 2], data[:, 3])


def aided_heading_in_process(rec: Path, every: int = 4,
                             params: dict | None = None) -> tuple[AidedReplayHeading, np.ndarray, np.ndarray]:
    """As `aided_replay_heading`, at every `every`-th sample and the last (the times, yaw, σ and flags as the
    command computes them, before its output's rounding), and every sample's time (from the first) and flags
    (YAW_RESET is set on one sample only): the estimator, its declination (the WMM at the first fix, today) and the validated fixes from
    the replay command's own functions (cli/replay.py), the recording's samples as it reads them, each fix offered
    before the first sample not earlier than its time of validity (estimator/fix_feed.py). `params`: the estimator's
    parameters to set beside the command's (as `--set` would)."""
    from ahrsd.cli import replay as command
    from ahrsd.drivers.gnss.validation import GnssFixValidator
    from ahrsd.drivers.recording import iter_samples
    from ahrsd.estimator import replay as replay_table
    from ahrsd.estimator.fix_feed import GnssFixFeed

    fixes, first_position = command._gnss_fixes(str(rec.with_suffix(".gnss.csv")), GnssFixValidator(name="replay"))
    no_position = argparse.Namespace(lat=None, lon=None, alt_m=0.0, date=None)
    params = command._told_calibration_sigma("ins", None, dict(params or {}))
    est = command._make_estimator("ins", command._declination_rad(no_position, first_position), params, aided=True)
    feed = GnssFixFeed(est, fixes)
    rows, all_flags = [], []
    k = view = None
    for k, sample in enumerate(iter_samples(rec, strict=False)):
        feed.offer_until(sample.t_s)
        view = est.step(sample)
        all_flags.append(int(view.flags))
        if k % every == 0:
            rows.append(replay_table._attitude_columns(sample.t_s, view.snapshot()))
    if k % every:                                 # the last sample, when not read above
        rows.append(replay_table._attitude_columns(sample.t_s, view.snapshot()))
    # the replay table's own rows, turned to true north as the command turns them
    table = replay_table._finish_table(rows, true_north=True)
    col = {c: replay_table.ATTITUDE_COLUMNS.index(c) for c in ("t_s", "yaw_deg", "sigma_yaw_deg", "flags")}
    n = len(all_flags)
    index = np.r_[np.arange(0, n, every), [n - 1] if (n - 1) % every else []].astype(int)
    t_rec, truth_yaw = _truth_yaw_deg(rec, index)
    return (_heading(table[:, col["t_s"]], t_rec[0], table[:, col["yaw_deg"]], truth_yaw,
                     table[:, col["sigma_yaw_deg"]], table[:, col["flags"]]),
            t_rec - t_rec[0], np.array(all_flags, dtype=np.int64))
