"""bench/yaw_drift_trace.py `--pooled`: the windows' normalised errors against the truth, pooled (docs/gnss.md "(win37)").
The truth here is written by hand, not computed by the bench."""

from __future__ import annotations

import pytest

from bench.yaw_drift_trace import _run_arg, pooled_summary


def _window(span_s, fit, sigma, turn_on, in_force, scale_share, turn_deg):
    """A window as trace() records it: only the fields pooled_summary reads are meaningful."""
    return (span_s, 0.0, fit, sigma, turn_on, 0.0, 0.0, (), (in_force, scale_share, turn_deg))


def _figures(lines, label, group):
    line = next(x for x in lines if x.strip().startswith(label) and f" {group}" in x)
    cells = [c.split() for c in line.split("|")]
    return int(cells[0][-1]), float(cells[1][-1]), float(cells[2][-2]), float(cells[3][-2])


def test_the_pooled_figures_are_the_windows_normalised_errors():
    windows = [
        # fit 10 ± 10: against the turn-on 0 z = 1; against the bias in force −20 z = 3; with the scale +5 z = 2.5
        _window(30.0, 10.0, 10.0, 0.0, -20.0, 5.0, 1.0),
        # fit −31 ± 10: turn-on 0 → z −3.1; in force −30 → −0.1; with the scale +1 → −0.2
        _window(15.0, -31.0, 10.0, 0.0, -30.0, 1.0, -4.8),
    ]
    lines = pooled_summary(windows)
    n, rms, beyond2, beyond3 = _figures(lines, "turn-on b_z", "all")
    assert (n, beyond2, beyond3) == (2, 50.0, 50.0) and rms == pytest.approx(((1 + 9.61) / 2) ** 0.5, abs=0.005)
    n, rms, beyond2, beyond3 = _figures(lines, "b_z in force  ", "all")
    assert (n, beyond2, beyond3) == (2, 50.0, 0.0) and rms == pytest.approx(((9 + 0.01) / 2) ** 0.5, abs=0.005)
    n, rms, beyond2, beyond3 = _figures(lines, "b_z in force + s_z", "all")
    assert (n, beyond2, beyond3) == (2, 50.0, 0.0) and rms == pytest.approx(((6.25 + 0.04) / 2) ** 0.5, abs=0.005)
    # split by the turn's size (the second window turned 4.8° to the right) and the window's length
    assert _figures(lines, "b_z in force + s_z", "turn 0–3°")[:2] == (1, 2.5)
    assert _figures(lines, "b_z in force + s_z", "turn ≥4.5°")[:2] == (1, 0.2)
    assert _figures(lines, "b_z in force + s_z", "span ≥29.9 s")[:2] == (1, 2.5)


def test_runs_take_a_southern_site_with_its_seeds():
    assert _run_arg("-53.16,-70.91:91,92") == ("-53.16,-70.91", [91, 92])
