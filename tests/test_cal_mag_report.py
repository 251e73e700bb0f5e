"""`ahrsd calibrate mag` leads with what the operator decides on (verdict, predicted heading error, coverage,
residuals) and keeps the fit's internals (optimiser messages, the paper's sphere fit, the fit's own CPU time) out."""

from __future__ import annotations

import pytest

from ahrsd.cli import main as cli
from ahrsd.simulation import simulate

from support.recordings import write_block


@pytest.fixture(scope="module")
def turning_boat(tmp_path_factory):
    path = tmp_path_factory.mktemp("magreport") / "turns.csv"
    block = simulate("level-turns", 120, rate_hz=50.0, seed=5)
    return write_block(path, block)


def test_the_report_leads_with_the_decision_and_hides_internals(turning_boat, tmp_path, capsys):
    code = cli.main(["calibrate", "mag", "--method", "backstepping", str(turning_boat), "--lat", "36.42", "--lon",
                     "54.98", "--state-dir", str(tmp_path / "s")])
    out = capsys.readouterr().out
    assert code == 0, out
    lines = out.splitlines()
    assert lines[0].startswith("Magnetometer calibration (backstepping)")
    assert lines[1].startswith("  verdict: accepted, saved to ")
    assert lines[2].startswith("  predicted heading error (1σ): ")
    assert lines[3].startswith("  coverage: headings ")
    assert lines[4].startswith("  residual: |m| − |F| RMS ")
    assert lines.index("  details:") > lines.index(next(l for l in lines if l.startswith("  hard iron (µT)")))
    for internal in ("sphere_fit_paper", "ftol", "termination", "time_s", "nfev", ": inf"):
        assert internal not in out, internal


def test_a_refused_fit_says_so_first(tmp_path, capsys):
    import numpy as np

    from ahrsd.drivers.recording import RECORDING_HEADER

    rec = tmp_path / "still.csv"          # one attitude: nothing to fit a magnetometer model to
    t = np.arange(3000) / 50.0
    table = np.column_stack([t, np.zeros((len(t), 3)), np.tile([0, 0, -9.81], (len(t), 1)),
                             np.tile([20.0, 1.0, 45.0], (len(t), 1)) + np.random.default_rng(1).normal(0, 0.05,
                                                                                                  (len(t), 3))])
    np.savetxt(rec, table, delimiter=",", fmt="%.6f", header=RECORDING_HEADER, comments="")
    code = cli.main(["calibrate", "mag", "--method", "backstepping", str(rec), "--lat", "36.42", "--lon", "54.98",
                     "--state-dir", str(tmp_path / "s")])
    out = capsys.readouterr().out
    assert code == 1
    assert out.splitlines()[1].startswith("  verdict: REFUSED: ")


def test_saving_in_the_services_directory_says_how_run_by_hand_reads_it(turning_boat, tmp_path, capsys,
                                                                        monkeypatch):
    """The default --state-dir is the service's (/var/lib/ahrsd) while `ahrsd run` by hand reads
    ~/.local/state/ahrsd: the report says so (a fresh clone's calibrate-then-run silently ran uncalibrated).
    The default is pointed at a temporary directory here; an explicit other --state-dir gets no hint."""
    import ahrsd.cli.calibrate as calibrate_cli

    service_dir = str(tmp_path / "service")
    monkeypatch.setattr(calibrate_cli, "DEFAULT_STATE_DIR", service_dir)
    args = ["calibrate", "mag", "--method", "backstepping", str(turning_boat), "--lat", "36.42", "--lon", "54.98"]
    assert cli.main(args) == 0
    verdict = capsys.readouterr().out.splitlines()[1]
    assert verdict.endswith(f"`ahrsd run` by hand only with --state-dir {service_dir}"), verdict
    assert cli.main(args + ["--state-dir", str(tmp_path / "mine")]) == 0
    assert "by hand" not in capsys.readouterr().out
