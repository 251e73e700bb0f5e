"""`ahrsd log list` on a missing directory says how a hand-started daemon keeps logs (it keeps none by default),
instead of naming the same default directory twice."""

from __future__ import annotations

from ahrsd.cli.main import main


def test_missing_log_directory_says_how_to_get_logs(tmp_path, capsys):
    assert main(["log", "list", "--dir", str(tmp_path / "none")]) == 1
    err = capsys.readouterr().err
    assert "no such log directory" in err
    assert "--log-dir DIR" in err and "[log] enabled = true" in err
    import ahrsd.core.state_dir as state_dir

    assert err.count(str(state_dir.SERVICE_STATE_DIR / "logs")) == 1     # the service's (conftest moves it)
