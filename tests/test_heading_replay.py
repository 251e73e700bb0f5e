"""`ahrsd replay --gnss` of a vehicle recorded without a magnetometer calibration (what a new user does first):
the output carries the GNSS yaw, its σ and the heading state, and the summary names the heading states."""

from __future__ import annotations

import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.cli.main import main
from ahrsd.cli.replay import AIDED_OUTPUT_HEADER, HEADING_OUTPUT_COLUMNS
from ahrsd.core.estimate import HeadingState

pytestmark = pytest.mark.slow     # a long file: started first under pytest-xdist (tests/conftest.py)

SEED = 2


def test_an_uncalibrated_boat_replays_with_an_honest_heading(tmp_path, capsys, caplog):
    """`record` and `replay` run in this process (the worker has usually loaded the ins kernels already; the
    console scripts in subprocesses are test_recording's and test_replay's)."""
    from ahrsd.simulation import open_stream

    rec = tmp_path / "boat.csv"
    # seed 2: its heading errors reach into the σ the filter publishes, so the σ checks below fail on a σ a quarter
    # or four times as large (mutations ins-published-yaw-sigma-whole / -informative). At the chip's quarter rate
    # (204.8 SPS: a quarter of the samples to record and replay) those breaks and the hysteresis's fail as at 819.2
    assert main(["record", "--sim", "boat", "--seconds", "90", "--seed", str(SEED), "--rate-hz", "204.8",
                 "-o", str(rec)]) == 0, capsys.readouterr().err
    capsys.readouterr()
    out = tmp_path / "out.csv"
    code = main(["replay", str(rec), "--gnss", str(tmp_path / "boat.gnss.csv"), "-o", str(out)])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "heading state" in err and "unknown" in err, err
    # the summary's disagreement is the one the log line gave at the (one) rejection, and says which it is
    logged = re.findall(r"disagrees with the GNSS-held heading by ([0-9.]+)°", caplog.text)
    summary = re.findall(r"disagreed with GNSS by ([0-9.]+)° when rejected", err)
    assert len(logged) == 1 and summary == logged, (logged, err)
    assert "when rejected: magnetometer not calibrated (no --calibration)" in err, err    # no calibration given
    lines = out.read_text().splitlines()
    assert lines[0] == AIDED_OUTPUT_HEADER and lines[0].endswith(",".join(HEADING_OUTPUT_COLUMNS))
    cols = lines[0].split(",")
    data = np.loadtxt(out, delimiter=",", skiprows=1)
    t = data[:, 0]
    late = t > 30.0
    state = data[late, cols.index("heading_state")].astype(int)
    # the recording's magnetometer is raw (vehicle iron, no calibration): never "magnetometer" as the reference
    assert not np.any(state == int(HeadingState.MAGNETOMETER)), np.unique(state)
    truth = open_stream("boat", seed=SEED, errors="ideal").truth_at(t[late])    # the simulator's, not the filter's
    q = truth.q_wxyz
    truth_yaw = Rotation.from_quat(np.column_stack([q[:, 1:], q[:, :1]])).as_euler("ZYX", degrees=True)[:, 0]
    err = (data[late, cols.index("yaw_deg")] - truth_yaw + 180.0) % 360.0 - 180.0
    sigma = data[late, cols.index("sigma_yaw_deg")]
    z = np.abs(err) / sigma
    # honest: at most 1 % of the errors beyond 3σ (not overconfident) …
    assert np.mean(z <= 3.0) >= 0.99, (np.sqrt(np.mean(err ** 2)), np.median(sigma), np.quantile(z, 0.99))
    # … and informative: the errors use the σ (a σ four times too large would claim less than the filter knows)
    assert np.sqrt(np.mean(z ** 2)) >= 0.3, (np.sqrt(np.mean(err ** 2)), np.median(sigma))
    gsf_sigma = data[late, cols.index("gsf_sigma_deg")]
    assert np.any(np.isfinite(gsf_sigma))
    # the state does not flap while the GNSS-held σ hovers at the 15° UNKNOWN limit (heading_state_hold.py):
    # 3 changes on this run, 7 without the hysteresis (--set heading_state_hold_s=0)
    all_states = data[:, cols.index("heading_state")].astype(int)
    at = np.flatnonzero(np.diff(all_states)) + 1
    assert len(at) <= 4, (len(at), t[at], all_states[at])
    # … and never claims a known heading with a σ beyond that limit (a worse state is published at once)
    beyond = data[:, cols.index("sigma_yaw_deg")] > 15.0
    assert np.all(all_states[beyond] == int(HeadingState.UNKNOWN))
