"""bench/replay_truth.py: a replay's errors against the recording's truth, on rows built with known errors."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from bench.replay_truth import main

RATE_HZ = 819.2


def _write(tmp_path, n=400):
    t = 0.0135626666 + np.arange(n) / RATE_HZ          # full precision in the recording, µs in the attitude CSV
    roll, pitch, yaw = 10.0, -5.0, 359.0 - 0.01 * np.arange(n)
    q = Rotation.from_euler("ZYX", np.column_stack([yaw, np.full(n, pitch), np.full(n, roll)]), degrees=True).as_quat()
    rec = tmp_path / "rec.csv"
    with rec.open("w") as f:
        f.write("t_s,truth_qw,truth_qx,truth_qy,truth_qz\n")
        for k in range(n):
            f.write(f"{t[k]:.17g},{q[k, 3]:.17g},{q[k, 0]:.17g},{q[k, 1]:.17g},{q[k, 2]:.17g}\n")
    att = tmp_path / "att.csv"
    with att.open("w") as f:
        f.write("t_s,roll_deg,pitch_deg,heading_true_deg,sigma_roll_deg,sigma_pitch_deg,sigma_yaw_deg\n")
        for k in range(n):
            # roll 1° off (σ 0.5: within 3σ), heading 2° off across north (σ 0.5: beyond), pitch exact (σ 1°) but
            # in rows 200…299 (0.1° off, σ 0.01°: beyond their own 3σ, not the median σ's)
            dp, sp = (0.1, 0.01) if 200 <= k < 300 else (0.0, 1.0)
            f.write(f"{t[k]:.6f},{roll + 1.0:.6f},{pitch + dp:.6f},{(yaw[k] + 2.0) % 360.0:.6f},0.5,{sp},0.5\n")
    return att, rec


def test_errors_sigma_and_share_beyond_3_sigma_against_the_truth(tmp_path, capsys):
    att, rec = _write(tmp_path)
    assert main([str(att), str(rec)]) == 0
    out = capsys.readouterr().out
    assert "400 samples from 0 s" in out, out
    lines = {line.split()[0]: line.split() for line in out.splitlines()[1:]}
    assert lines["roll"][2] == "1.00°" and lines["roll"][8] == "0.00", out
    assert lines["pitch"][2] == f"{np.sqrt(100 / 400 * 0.01):.2f}°" and lines["pitch"][8] == "25.00", out
    assert lines["heading"][2] == "2.00°" and lines["heading"][8] == "100.00", out


def test_from_s_leaves_the_first_samples_out(tmp_path, capsys):
    att, rec = _write(tmp_path)
    main([str(att), str(rec), "--from-s", str(300 / RATE_HZ - 1e-4)])
    out = capsys.readouterr().out
    assert "100 samples from" in out, out
    assert "pitch    RMS   0.00°" in out, out
