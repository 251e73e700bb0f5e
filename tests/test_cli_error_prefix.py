"""#30 item 13: every command says a failure as `ahrsd COMMAND: error: …` on stderr, the form argparse uses for a
usage error (`ahrsd replay: error: the following arguments are required: …`)."""

from __future__ import annotations

import socket

import pytest

from ahrsd.cli.main import main


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


CASES = [
    (["record", "--sim", "nosuch", "--seconds", "1", "-o", "{tmp}/x.csv"], "ahrsd record: error: unknown scenario"),
    (["run", "--replay", "{tmp}/nope.csv", "--sim-faults", "stall@1-2"], "ahrsd run: error: --sim-faults needs"),
    (["magcal", "--connect", "nonsense:", "status"], "ahrsd magcal: error: cannot open nonsense:"),
    (["magcal", "--connect", "udpin:127.0.0.1:{port}", "--timeout", "0.5", "status"],
     "ahrsd magcal: error: no ahrsd heard on"),
    (["magcal", "--connect", "udpin:127.0.0.1:{port}", "fixed-yaw", "10", "--lat", "1"],
     "ahrsd magcal fixed-yaw: error: give --lat and --lon together"),
    (["replay", "{tmp}/nope.csv", "-o", "{tmp}/o.csv"], "ahrsd replay: error: "),
    (["log", "list", "--dir", "{tmp}/none"], "ahrsd log list: error: "),
    # walk30: a traceback ending "ValueError: unknown scenario 'nosuch'; …" (the simulator's own check)
    (["calibrate", "accel", "--live", "--sim", "nosuch"], "ahrsd calibrate accel: error: unknown scenario 'nosuch'"),
]


@pytest.mark.parametrize("argv, start", CASES, ids=[c[1].split(":")[0] + " " + c[0][0] for c in CASES])
def test_a_failure_is_one_line_with_the_commands_error_prefix(argv, start, tmp_path, capsys):
    """(Seen failing on the old texts: "ahrsd record: unknown scenario …", "ahrsd: --sim-faults needs …",
    "cannot open …", "no ahrsd heard …", "ahrsd magcal fixed-yaw: give …".)"""
    port = _free_udp_port()
    args = [a.format(tmp=tmp_path, port=port) for a in argv]
    try:
        rc = main(args)
    except SystemExit as exc:
        rc = exc.code
    err = capsys.readouterr().err.strip().splitlines()
    assert rc != 0 and err and err[-1].startswith(start), err


def test_ctrl_c_is_said_and_exits_130(monkeypatch, tmp_path, capsys):
    """A replay stopped by Ctrl-C exited 130 without a word on the fresh clone (its output file discarded): the
    user could not tell it from a run that ended. (Seen failing on the old main: stderr empty.)"""
    import ahrsd.cli.replay as replay_cli

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(replay_cli, "run", interrupted)
    assert main(["replay", str(tmp_path / "r.csv"), "-o", str(tmp_path / "o.csv")]) == 130
    assert capsys.readouterr().err.strip().splitlines()[-1] == "ahrsd replay: interrupted"
