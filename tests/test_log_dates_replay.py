"""Logs written while the daemon replays a recording are dated by when the replay ran (its t_s is the
recording's own time, not the machine's monotonic clock): `log list` spans now, and the file name says so."""

from __future__ import annotations

import contextlib
import datetime as dt
import io
import json
import logging
import time

from ahrsd.cli.main import main


def ahrsd(*args) -> tuple[int, str]:
    """`ahrsd ARGS` by its main in this process, as the console script calls it (what is checked is the logs'
    dates, not a process): the exit code and what it printed on stdout. `ahrsd run` lets the daemon's INFO
    through: the `ahrsd` logger's level is restored after."""
    ours = logging.getLogger("ahrsd")
    level = ours.level
    out, err = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            rc = main([str(a) for a in args])
    finally:
        ours.setLevel(level)
    assert rc == 0, err.getvalue()[-2000:]
    return rc, out.getvalue()


def test_a_replays_logs_are_dated_when_it_ran(tmp_path):
    rec, logs = tmp_path / "rec.csv", tmp_path / "logs"
    ahrsd("record", "--sim", "static", "--seconds", "3", "--output", rec, "--quiet")
    before = time.time()
    ahrsd("run", "--replay", rec, "--replay-speed", "20", "--log-dir", logs, "--status-line", "off",
          "--state-dir", tmp_path / "s", "--mavlink", "udpout:127.0.0.1:9")
    after = time.time()
    _, listed = ahrsd("log", "list", "--dir", logs, "--json")
    samples = [json.loads(line) for line in listed.splitlines() if json.loads(line)["kind"] == "samples"]
    assert samples, listed
    for entry in samples:
        start = dt.datetime.fromisoformat(entry["start_utc"].replace("Z", "+00:00")).timestamp()
        end = dt.datetime.fromisoformat(entry["end_utc"].replace("Z", "+00:00")).timestamp()
        # not boot time + t_s: the replay's start, and the recording's own span after it (at 20× the run itself
        # is shorter than the 3 s it replays, so the end may lie after the run ended)
        assert before - 2 <= start <= after + 2, (entry, before, after)
        assert 2.0 <= end - start <= 3.5, (entry, end - start)
        stamp = dt.datetime.strptime(entry["file"].rsplit("/", 1)[-1].split("-", 1)[1][:15], "%Y%m%dT%H%M%S")
        assert abs(stamp.replace(tzinfo=dt.timezone.utc).timestamp() - start) < 2
