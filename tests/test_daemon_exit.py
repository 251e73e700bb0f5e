"""The console entry ends a stopped daemon's process with os._exit, past the interpreter's teardown
(cli/main.py console_main): what the daemon wrote must be complete all the same, and the exit code kept.

Each run goes through console_main in a fresh interpreter with an atexit hook: the hook's line missing from
stderr says the teardown was skipped, so these tests check the files after the fast exit, not after a normal one."""

from __future__ import annotations

import gzip
import json
import subprocess
import sys

from ahrsd.drivers.recording import RECORDING_HEADER

ROW = "{t:.6f},0.001,-0.002,0.0005,0.05,-0.03,-9.80665,20.0,1.5,45.0\n"
RATE_HZ = 819.2
TEARDOWN = "the interpreter's teardown ran"

CONSOLE = f"""
import atexit, sys
atexit.register(lambda: print({TEARDOWN!r}, file=sys.stderr))
sys.argv[0] = "ahrsd"
from ahrsd.cli.main import console_main
console_main()
"""


def write_recording(path, rows, tail=""):
    path.write_text(RECORDING_HEADER + "\n" + "".join(ROW.format(t=k / RATE_HZ) for k in range(rows)) + tail)
    return path


def run_console(tmp_path, recording):
    return subprocess.run(
        [sys.executable, "-c", CONSOLE, "run", "--replay", recording, "--replay-speed", "50", "--status-line", "off",
         "--state-dir", tmp_path / "state", "--log-dir", tmp_path / "logs", "--mavlink", "udpout:127.0.0.1:9",
         "--stats-file", tmp_path / "stats.json"],
        capture_output=True, text=True, timeout=300)


def test_a_stopped_daemon_exits_past_the_teardown_with_its_log_stats_and_state_complete(tmp_path):
    rows = 2000
    r = run_console(tmp_path, write_recording(tmp_path / "rec.csv", rows))
    assert r.returncode == 0, r.stderr
    assert TEARDOWN not in r.stderr                    # the fast exit was taken
    assert r.stderr.rstrip().endswith("ahrsd: stopping"), r.stderr[-400:]   # the last log line, whole
    stats = json.loads((tmp_path / "stats.json").read_text())               # written whole
    assert stats["exit_code"] == 0
    # the samples' log: a gzip stream read to its end-of-stream marker (an unclosed file has none), every row
    logged = [f for f in (tmp_path / "logs").iterdir() if f.name.endswith(".csv.gz")]
    assert len(logged) == 1
    with gzip.open(logged[0], "rt") as f:
        lines = f.read().splitlines()
    assert len(lines) - 1 == rows and lines[-1].split(",")[0] == f"{(rows - 1) / RATE_HZ:.6f}"
    for sidecar in (tmp_path / "logs").glob("*.json"):
        json.loads(sidecar.read_text())                # the samples' and the .tlog's sidecars whole
    for state_file in (tmp_path / "state").glob("*.json"):
        json.loads(state_file.read_text())             # each state file whole


def test_a_failed_run_still_exits_non_zero_past_the_teardown(tmp_path):
    bad_row = write_recording(tmp_path / "bad.csv", 1000, tail="0.3,1,2\n" + ROW.format(t=0.31))
    r = run_console(tmp_path, bad_row)
    assert r.returncode == 1, r.stderr
    assert TEARDOWN not in r.stderr
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith("ahrsd run: error: the replay stopped early:") and "line 1002" in last


def test_a_daemon_stopped_while_its_sensor_fails_stops_without_a_traceback(tmp_path):
    """Ctrl-C (SIGINT) of a daemon whose sensor has failed — walk27: the shipped config on a computer with no
    /dev/spidev0.0, and the same with the simulated chip gone (`--sim-faults bus_error@1-100`) — printed two
    tracebacks after "ahrsd: stopping": the reader process's final drain re-raised the sensor's failure
    ("Process ahrsd-sensor-reader: … SensorUnavailable"), and a retry armed by a look queued before the stop
    re-registered the closed pipe ("Exception in callback SampleReader._batch_retry() … Bad file descriptor")."""
    import os
    import signal
    import time

    proc = subprocess.Popen(
        [sys.executable, "-m", "ahrsd.cli", "run", "--sim-faults", "bus_error@1-100", "--status-line", "off",
         "--state-dir", str(tmp_path / "state"), "--no-log", "--mavlink", "udpout:127.0.0.1:9"],
        stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    try:
        deadline = time.monotonic() + 240                  # a first compile included, at load 10
        for line in proc.stderr:
            lines.append(line)
            if "sensor failure" in line or time.monotonic() > deadline:
                break
        assert any("sensor failure" in line for line in lines), "".join(lines[-20:])
        time.sleep(1.0)                                    # the reader's retries (0.2 s) go on meanwhile
        os.kill(proc.pid, signal.SIGINT)
        _, rest = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    after = "".join(lines) + rest
    assert "Traceback" not in after and "Exception in callback" not in after, after[-3000:]
    assert proc.returncode == 0
