"""Logs written while the daemon replays a recording are dated by when the replay ran (its t_s is the
recording's own time, not the machine's monotonic clock): `log list` spans now, and the file name says so."""

from __future__ import annotations

import datetime as dt
import json
import subprocess
import sys
import time


def ahrsd(*args, timeout=300):
    return subprocess.run([sys.executable, "-m", "ahrsd.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


def test_a_replays_logs_are_dated_when_it_ran(tmp_path):
    rec, logs = tmp_path / "rec.csv", tmp_path / "logs"
    r = ahrsd("record", "--sim", "static", "--seconds", "3", "--output", rec, "--quiet")
    assert r.returncode == 0, r.stderr
    before = time.time()
    r = ahrsd("run", "--replay", rec, "--replay-speed", "20", "--log-dir", logs, "--status-line", "off",
              "--state-dir", tmp_path / "s", "--mavlink", "udpout:127.0.0.1:9")
    after = time.time()
    assert r.returncode == 0, r.stderr
    r = ahrsd("log", "list", "--dir", logs, "--json")
    assert r.returncode == 0, r.stderr
    samples = [json.loads(line) for line in r.stdout.splitlines() if json.loads(line)["kind"] == "samples"]
    assert samples, r.stdout
    for entry in samples:
        start = dt.datetime.fromisoformat(entry["start_utc"].replace("Z", "+00:00")).timestamp()
        end = dt.datetime.fromisoformat(entry["end_utc"].replace("Z", "+00:00")).timestamp()
        # not boot time + t_s: the replay's start, and the recording's own span after it (at 20× the run itself
        # is shorter than the 3 s it replays, so the end may lie after the run ended)
        assert before - 2 <= start <= after + 2, (entry, before, after)
        assert 2.0 <= end - start <= 3.5, (entry, end - start)
        stamp = dt.datetime.strptime(entry["file"].rsplit("/", 1)[-1].split("-", 1)[1][:15], "%Y%m%dT%H%M%S")
        assert abs(stamp.replace(tzinfo=dt.timezone.utc).timestamp() - start) < 2
