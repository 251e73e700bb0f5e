"""A failed run exits non-zero with one line; a recording cut mid-row (a recorder killed) is used up to its last
complete row, with a warning naming the line, by `run --replay`, `replay` and `calibrate`."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from ahrsd.cli import main as cli
from ahrsd.drivers.recording import RECORDING_HEADER, RecordingFormatError, read_recording

ROW = "{t:.6f},0.001,-0.002,0.0005,0.05,-0.03,-9.80665,20.0,1.5,45.0\n"


def ahrsd(*args, timeout=180):
    """`python -m ahrsd.cli ARGS` as a process: its exit code and the lines it printed. The process boundary is
    test_run_replay_of_a_missing_file_fails_at_once_in_one_line's; the others run `ahrsd_inproc`."""
    return subprocess.run([sys.executable, "-m", "ahrsd.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


@pytest.fixture
def ahrsd_inproc(capsys):
    """`ahrsd ARGS` by its main in this process (no interpreter start and imports per call): the exit code, and as
    its stderr what the process would print there, in order — what main wrote to stderr and every log record that
    reached the root logger (in the process `logging.basicConfig`'s handler prints them; here a handler on the
    captured stderr for the call; `ahrsd run` lets the daemon's INFO through, and so here, restored after)."""
    import logging

    def run(*args):
        argv = [str(a) for a in args]
        ours, root = logging.getLogger("ahrsd"), logging.getLogger()
        level = ours.level
        capsys.readouterr()
        printed = logging.StreamHandler(sys.stderr)        # pytest's capture of stderr, as main's prints
        printed.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
        root.addHandler(printed)
        try:
            rc = cli.main(argv)
        except SystemExit as exc:      # argparse's usage errors
            rc = exc.code
        finally:
            root.removeHandler(printed)
            ours.setLevel(level)
        out, err = capsys.readouterr()
        return subprocess.CompletedProcess(["ahrsd", *argv], rc, out, err)

    return run


def write_rows(path, n, rate_hz=819.2, tail=""):
    path.write_text(RECORDING_HEADER + "\n" + "".join(ROW.format(t=k / rate_hz) for k in range(n)) + tail)
    return path


@pytest.fixture
def cut_file(tmp_path):
    """1000 complete rows, then a row cut in its fourth field (line 1002, no newline)."""
    return write_rows(tmp_path / "cut.csv", 1000, tail="0.25,0.001,-0.0")


def test_run_replay_of_a_missing_file_fails_at_once_in_one_line(tmp_path):
    r = ahrsd("run", "--replay", tmp_path / "missing.csv", "--no-log", "--status-line", "off",
              "--state-dir", tmp_path / "s", "--mavlink", "udpout:127.0.0.1:9")
    assert r.returncode == 1
    assert r.stderr.strip().splitlines() == [f"ahrsd run: error: cannot replay {tmp_path / 'missing.csv'}: "
                                             "No such file or directory"]


def test_run_replay_of_a_bad_header_fails_in_one_line(tmp_path, ahrsd_inproc):
    bad = tmp_path / "bad.csv"
    bad.write_text("time,gx\n1,2\n")
    r = ahrsd_inproc("run", "--replay", bad, "--no-log", "--status-line", "off", "--state-dir", tmp_path / "s")
    assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1
    assert "ahrsd run: error: cannot replay" in r.stderr and "'t_s'" in r.stderr


def test_run_replay_of_a_missing_or_bad_gnss_recording_fails_at_once_in_one_line(tmp_path, ahrsd_inproc):
    """The GNSS recording beside the IMU one is checked as the IMU one is: before the state directory is used and
    the ins compiles, one line, exit 1 (walk27: it failed after the compile and the start-up logs, as an ERROR log
    line "ahrsd cannot start: missing.gnss.csv: cannot read: [Errno 2] No such file or directory: …")."""
    rec = write_rows(tmp_path / "rec.csv", 100)
    common = ("--no-log", "--status-line", "off", "--state-dir", tmp_path / "s", "--mavlink", "udpout:127.0.0.1:9")
    r = ahrsd_inproc("run", "--replay", rec, "--gnss-replay", tmp_path / "missing.gnss.csv", *common)
    assert r.returncode == 1
    assert r.stderr.strip().splitlines() == [f"ahrsd run: error: cannot replay the GNSS recording "
                                             f"{tmp_path / 'missing.gnss.csv'}: cannot read: No such file or directory"]
    bad = tmp_path / "bad.gnss.csv"
    bad.write_text("time,lat\n1,2\n")
    r = ahrsd_inproc("run", "--replay", rec, "--gnss-replay", bad, *common)
    assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert r.stderr.startswith("ahrsd run: error: cannot replay the GNSS recording") and "'time'" in r.stderr


def test_run_with_a_signing_key_it_cannot_read_fails_at_once_in_one_line(tmp_path, ahrsd_inproc):
    """[signing] key_file missing or malformed: one line, exit 1, before the compile (walk27: it failed after the
    compile and the start-up logs, as an ERROR log line "ahrsd cannot start: signing.key_file …"; on a Raspberry
    Pi a first compile takes minutes)."""
    rec = write_rows(tmp_path / "rec.csv", 100)
    for key, why in ((tmp_path / "missing.key", "cannot read (No such file or directory)"),
                     (tmp_path / "short.key", "expected 32 raw bytes or 64 hex characters")):
        if key.name == "short.key":
            key.write_text("abcd\n")
        cfg = tmp_path / f"{key.stem}.toml"
        cfg.write_text(f'[signing]\nkey_file = "{key}"\n')
        r = ahrsd_inproc("run", "--config", cfg, "--replay", rec, "--no-log", "--status-line", "off",
                  "--state-dir", tmp_path / "s", "--mavlink", "udpout:127.0.0.1:9")
        assert r.returncode == 1
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"ahrsd run: error: signing.key_file {key}: {why}"), r.stderr


def test_run_with_a_mavlink_server_address_it_cannot_have_fails_at_once_in_one_line(tmp_path, ahrsd_inproc):
    """`--mavlink udpin:` on an address that is not this machine's, and `tcpin:` (or `--nmea tcpserver:`) on a
    port another socket listens on: one line naming the endpoint and the reason, exit 1, before the compile
    (walk27: exit 1, but as an ERROR log line after the compile and the start-up lines, "[Errno 99]" first)."""
    import socket

    rec = write_rows(tmp_path / "rec.csv", 100)
    taken = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    taken.bind(("127.0.0.1", 0))
    taken.listen(1)
    port = taken.getsockname()[1]
    try:
        for url, why in (("udpin:192.0.2.1:14550", "Cannot assign requested address"),   # TEST-NET-1
                         (f"tcpin:127.0.0.1:{port}", "Address already in use")):
            r = ahrsd_inproc("run", "--replay", rec, "--no-log", "--status-line", "off", "--state-dir", tmp_path / "s",
                      "--mavlink", "udpout:127.0.0.1:9", "--mavlink", url)
            assert r.returncode == 1
            assert r.stderr.strip().splitlines() == [f"ahrsd run: error: MAVLink endpoint {url}: {why}"], r.stderr
        # an NMEA TCP server output on the taken port: the same, naming the output (was: after the compile)
        r = ahrsd_inproc("run", "--replay", rec, "--no-log", "--status-line", "off", "--state-dir", tmp_path / "s",
                  "--mavlink", "udpout:127.0.0.1:9", "--nmea", f"tcpserver:127.0.0.1:{port}")
        assert r.returncode == 1
        assert r.stderr.strip().splitlines() == [f"ahrsd run: error: NMEA output tcpserver:127.0.0.1:{port}: cannot "
                                                 f"listen on 127.0.0.1:{port}: Address already in use"], r.stderr
    finally:
        taken.close()


def test_the_daemons_own_endpoint_error_names_the_endpoint_without_the_errno_first():
    """The daemon's start (daemon.service: "ahrsd cannot start: …") meets the same error when the address goes
    between the command's check and the start: the same text."""
    import asyncio

    from ahrsd.daemon.mavlink_io import Endpoint, EndpointOpenError

    loop = asyncio.new_event_loop()
    try:
        with pytest.raises(EndpointOpenError) as err:
            Endpoint("udpin:192.0.2.1:14550", 1, 200, lambda _ep, _msg: None).open(loop)
    finally:
        loop.close()
    assert str(err.value) == "MAVLink endpoint udpin:192.0.2.1:14550: Cannot assign requested address"


def test_run_replay_that_meets_a_bad_row_exits_non_zero_and_a_cut_one_replays_to_the_end(tmp_path, cut_file, ahrsd_inproc):
    bad = write_rows(tmp_path / "bad_row.csv", 1000, tail="0.3,1,2\n" + ROW.format(t=0.31))
    common = ("--no-log", "--status-line", "off", "--state-dir", tmp_path / "s", "--mavlink", "udpout:127.0.0.1:9",
              "--replay-speed", "50")
    r = ahrsd_inproc("run", "--replay", bad, *common)
    assert r.returncode == 1, r.stderr
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith("ahrsd run: error: the replay stopped early:") and "line 1002" in last
    r = ahrsd_inproc("run", "--replay", cut_file, *common)
    assert r.returncode == 0, r.stderr
    assert "line 1002 is incomplete" in r.stderr and "using the 1000 complete rows" in r.stderr
    assert "replay finished" in r.stderr


def test_replay_uses_the_complete_rows_of_a_cut_file(tmp_path, cut_file, caplog):
    out = tmp_path / "att.csv"
    assert cli.main(["replay", str(cut_file), "-o", str(out), "-q", "-e", "thesis"]) == 0
    assert len(out.read_text().splitlines()) == 1 + 1000
    assert "line 1002 is incomplete" in caplog.text


def test_calibrate_uses_the_complete_rows_of_a_cut_file(tmp_path, cut_file, capsys, caplog):
    import json

    code = cli.main(["calibrate", "gyro", "--bias-only", str(cut_file), "--state-dir", str(tmp_path / "s"), "--json",
                     "--dry-run"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "line 1002 is incomplete" in caplog.text
    payload = json.loads(captured.out)
    assert payload["quality"]["n_used"] == 1000


def test_calibrate_allan_streams_the_complete_rows_of_a_cut_file(tmp_path, cut_file, capsys, caplog):
    import json

    code = cli.main(["calibrate", "allan", str(cut_file), "--state-dir", str(tmp_path / "s"), "--json", "--dry-run"])
    captured = capsys.readouterr()
    assert code == 0, captured.err               # not refused: the cut row is dropped, not reported as an error
    assert "line 1002 is incomplete" in caplog.text
    payload = json.loads(captured.out)
    assert payload["samples"] == 1000 and payload["duration_s"] == pytest.approx(1000 / 819.2, rel=1e-6)
    # the rows are constant: the analysis says so for every axis instead of reading a term
    for sensor in ("gyro", "accel", "mag"):
        for axis in "xyz":
            assert payload[sensor][axis]["white_noise"] is None
            assert payload[sensor][axis]["flags"] == ["constant signal or too few cluster sizes: no noise terms read"]


def test_a_cut_last_row_on_a_chunk_boundary_is_dropped_too(tmp_path):
    path = write_rows(tmp_path / "b.csv", 19, tail="0.9,0,0")     # line 21: the 20th line of the body, a chunk's last
    assert len(read_recording(path, strict=False, chunk_rows=10)) == 19
    with pytest.raises(RecordingFormatError, match="line 21"):
        read_recording(path, chunk_rows=10)


def test_a_full_row_without_its_final_newline_is_kept(tmp_path):
    path = write_rows(tmp_path / "n.csv", 5, tail=ROW.format(t=1.0).rstrip("\n"))
    r = read_recording(path, strict=False)
    assert len(r) == 6 and np.isclose(r.t_s[-1], 1.0)


def test_a_broken_config_and_a_missing_recording_fail_with_the_commands_error_prefix(tmp_path, capsys):
    """Every command's failure line reads `ahrsd COMMAND: error: …` (a new user met `ahrsd: config file …` from
    run and `ahrsd calibrate gyro: missing.csv: …` from calibrate beside `ahrsd run: error: …`)."""
    broken = tmp_path / "broken.toml"
    broken.write_text("[sensor\nsource=")
    assert cli.main(["run", "--config", str(broken)]) == 2
    assert capsys.readouterr().err.startswith(f"ahrsd run: error: config file {broken} is not valid TOML")
    assert cli.main(["calibrate", "gyro", str(tmp_path / "missing.csv"), "--state-dir", str(tmp_path / "s")]) == 1
    assert capsys.readouterr().err.startswith("ahrsd calibrate gyro: error: ")


def test_calibrate_mag_of_a_missing_file_says_so_first(tmp_path, capsys):
    """Without --lat/--lon and with no remembered position, a missing recording was met with the usage error about
    the calibration site (exit 2) — fix that, and the next run said the file is missing (walk26, walk27). The file
    comes first, as for `calibrate gyro` and `replay`."""
    code = cli.main(["calibrate", "mag", str(tmp_path / "missing.csv"), "--state-dir", str(tmp_path / "s"),
                     "--dry-run"])
    err = capsys.readouterr().err
    assert code == 1, err
    assert err.strip() == f"ahrsd calibrate mag: error: {tmp_path / 'missing.csv'}: no such file"
