"""tests/support/aided_replay_truth.py's in-process replay (the two one-test boat files' estimator) is `ahrsd replay
--gnss`'s: the same yaw, yaw σ and flags as the command's output file on one recording, to the output's rounding."""

from __future__ import annotations

import numpy as np

from ahrsd.cli.main import main
from support.aided_replay_truth import aided_heading_in_process, aided_replay_heading

ROUNDING = 5e-7 + 1e-9      # the output's %.6f (cli/replay.py), and the float sum the yaw's true north adds


def test_the_in_process_replay_is_the_commands(tmp_path, capsys):
    rec = tmp_path / "boat.csv"
    # the boat's GNSS from its start: the fixes and the declination at the first one play (the estimator's set-up
    # is what this compares, not its rate: a short recording at the chip's eighth rate)
    assert main(["record", "--sim", "boat", "--seconds", "30", "--seed", "17", "--rate-hz", "102.4", "-o", str(rec),
                 "--quiet"]) == 0, capsys.readouterr().err
    command = aided_replay_heading(rec, tmp_path / "out.csv")
    h, t_every, flags_every = aided_heading_in_process(rec, every=4)
    n = len(command.t_s)
    read = np.r_[np.arange(0, n, 4), [n - 1] if (n - 1) % 4 else []].astype(int)
    assert np.array_equal(flags_every, command.flags) and np.array_equal(h.flags, command.flags[read])
    assert np.max(np.abs(t_every - command.t_s)) < ROUNDING and np.max(np.abs(h.t_s - command.t_s[read])) < ROUNDING
    yaw, sigma = command.yaw_error_deg[read], command.sigma_yaw_deg[read]
    assert np.array_equal(np.isnan(h.yaw_error_deg), np.isnan(yaw)) and np.isfinite(yaw[-1])
    assert np.nanmax(np.abs(h.yaw_error_deg - yaw)) < ROUNDING, np.nanmax(np.abs(h.yaw_error_deg - yaw))
    assert np.max(np.abs(h.sigma_yaw_deg - sigma)) < ROUNDING, np.max(np.abs(h.sigma_yaw_deg - sigma))
