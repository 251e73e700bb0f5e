"""Progress bars on long offline work: shown (tqdm, with the rate and the time left) when stderr is a real
terminal — a tmux pane here — and absent in a pipe, with --quiet and with --json."""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
import tempfile
import time
import uuid

import pytest

from ahrsd.core.sample import make_sample
from ahrsd.simulation import simulate

from support.recordings import write_block

BAR_RATE = "sample/s"    # tqdm's rate field for unit="sample"


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("progress") / "tumble.csv"
    block = simulate("tumble", 120, rate_hz=100.0, seed=1)
    return write_block(path, block)


def in_tmux(command: list[str], timeout_s: float = 120.0) -> str:
    """Run `command` in a detached tmux pane (a real terminal) and return what the pane shows when it is done."""
    if shutil.which("tmux") is None:
        pytest.skip("tmux is not installed")
    session = f"ahrsd-test-{uuid.uuid4().hex[:8]}"
    # a tmux server of its own (-S): on the shared default server a new session could race the server's exit
    # after the previous test killed its last session (seen once in CI: new-session exit status 1)
    sock = os.path.join(tempfile.gettempdir(), f"{session}.tmux")
    tmux = ["tmux", "-S", sock]
    line = " ".join(f"'{c}'" for c in command) + "; echo __DONE__; sleep 600"
    started = subprocess.run([*tmux, "new-session", "-d", "-s", session, "-x", "200", "-y", "50", line],
                             capture_output=True, text=True)
    assert started.returncode == 0, f"tmux new-session: {started.stderr}"
    try:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            shown = subprocess.run([*tmux, "capture-pane", "-p", "-t", session], capture_output=True,
                                   text=True).stdout
            if "__DONE__" in shown:
                return shown
            time.sleep(0.2)
        raise AssertionError(f"the command did not finish in {timeout_s} s: {shown}")
    finally:
        subprocess.run([*tmux, "kill-server"], capture_output=True)
        with contextlib.suppress(FileNotFoundError):
            os.unlink(sock)


def ahrsd(*args) -> list[str]:
    return [sys.executable, "-m", "ahrsd.cli", *map(str, args)]


def test_replay_shows_a_bar_with_rate_and_time_left_in_a_terminal(recording, tmp_path):
    shown = in_tmux(ahrsd("replay", recording, "--output", tmp_path / "out.csv"))
    bar = [line for line in shown.splitlines() if line.startswith("replay")]
    assert bar and BAR_RATE in bar[-1] and "100%" in bar[-1], shown
    assert "<00:00" in bar[-1]          # the time-left field: elapsed<remaining
    assert "ahrsd replay: 12000 samples" in shown


def test_replay_in_a_terminal_with_quiet_has_no_bar(recording, tmp_path):
    out = tmp_path / "out.csv"
    shown = in_tmux(ahrsd("replay", recording, "--output", out, "--quiet"))
    assert BAR_RATE not in shown
    # the replay ran (a failed one shows no bar either) and printed nothing: no bar, no summary
    assert shown.strip().splitlines() == ["__DONE__"], shown
    assert len(out.read_text().splitlines()) == 1 + 12000


def test_calibrate_mag_shows_a_bar_while_reading_and_none_with_json(recording, tmp_path):
    args = ("calibrate", "mag", recording, "--lat", "36.42", "--lon", "54.98", "--dry-run", "--state-dir", tmp_path)
    shown = in_tmux(ahrsd(*args))
    assert any(line.startswith("reading tumble.csv") and BAR_RATE in line for line in shown.splitlines()), shown
    # the fit itself: a line with its elapsed time while it runs, "done" when it ends
    assert any(line.startswith("fitting (ellipsoid) 12000 samples: 00:") and line.endswith("done")
               for line in shown.splitlines()), shown
    with_json = in_tmux(ahrsd(*args, "--json"))
    assert BAR_RATE not in with_json and "fitting" not in with_json


def test_calibrate_allan_streams_with_a_bar_and_shows_the_analysis_in_a_terminal(recording, tmp_path):
    args = ("calibrate", "allan", recording, "--dry-run", "--state-dir", tmp_path)
    shown = in_tmux(["sh", "-c", " ".join(ahrsd(*args)) + " > /dev/null"])   # the report is longer than the pane
    lines = shown.splitlines()
    assert any(line.startswith("reading tumble.csv: 100%") and BAR_RATE in line for line in lines), shown
    assert any(line.startswith("Allan analysis: 00:") and line.endswith("done") for line in lines), shown
    with_json = in_tmux(["sh", "-c", " ".join(ahrsd(*args, "--json")) + " > /dev/null"])
    assert BAR_RATE not in with_json and "Allan analysis" not in with_json, with_json


def test_no_bar_in_a_pipe(recording, tmp_path, capsys):
    """stderr not a terminal (pytest's capture, as a pipe would be): `ahrsd replay`'s main in this process, as the
    console script calls it; the bar's terminal is the tmux tests' above."""
    from ahrsd.cli.main import main

    assert main(["replay", str(recording), "--output", str(tmp_path / "out.csv")]) == 0
    err = capsys.readouterr().err
    assert BAR_RATE not in err and "\r" not in err
    assert err.startswith("ahrsd replay: 12000 samples"), err[:300]


def test_log_cut_shows_a_bar_in_a_terminal(tmp_path):
    from ahrsd.drivers.sample_log import SampleLog

    with SampleLog(tmp_path / "logs") as log:
        for k in range(20_000):
            log.put(make_sample(k * 0.01, [0, 0, 0], [0, 0, -9.8], [20, 0, 40]))
    shown = in_tmux(ahrsd("log", "cut", "--dir", tmp_path / "logs", "--from", 10, "--to", 150,
                          "--output", tmp_path / "cut.csv"))
    bar = [line for line in shown.splitlines() if line.startswith("log cut")]
    assert bar and BAR_RATE in bar[-1] and "100%" in bar[-1] and "20.0k/20.0k" in bar[-1], shown
    quiet = in_tmux(ahrsd("log", "cut", "--dir", tmp_path / "logs", "--from", 10, "--to", 150,
                          "--output", tmp_path / "quiet.csv", "--quiet"))
    assert BAR_RATE not in quiet and (tmp_path / "quiet.csv").read_bytes() == (tmp_path / "cut.csv").read_bytes()
