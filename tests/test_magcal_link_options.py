"""`ahrsd magcal`'s link options (--connect, --target, --timeout) work before and after the action (issue 30
walk: `ahrsd magcal status --timeout 2`, the order a user types, was refused with the top-level usage,
"ahrsd: error: unrecognized arguments: --timeout 2", and docs/magcal-field.md's "the second client --connect
udpin:127.0.0.1:14551" reads as either order)."""

from __future__ import annotations

import socket

import pytest

from ahrsd.cli.main import build_parser, main


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("argv, connect, target, timeout", [
    (["magcal", "status"], "udpin:127.0.0.1:14550", None, 10.0),
    (["magcal", "--timeout", "3", "--target", "1:200", "status"], "udpin:127.0.0.1:14550", "1:200", 3.0),
    (["magcal", "status", "--timeout", "2", "--connect", "udpin:127.0.0.1:14551"], "udpin:127.0.0.1:14551", None, 2.0),
    # given before the action and not after: kept; given on both sides: the later one, as argparse does
    (["magcal", "--connect", "tcp:h:5760", "--timeout", "3", "start", "--accept"], "tcp:h:5760", None, 3.0),
    (["magcal", "--timeout", "3", "fixed-yaw", "90", "--timeout", "4"], "udpin:127.0.0.1:14550", None, 4.0),
])
def test_link_options_parse_on_either_side_of_the_action(argv, connect, target, timeout):
    args = build_parser().parse_args(argv)
    assert (args.connect, args.target, args.timeout) == (connect, target, timeout)


def test_an_option_after_the_action_reaches_the_client(capsys):
    """Nobody on a free port: the client waits the --timeout given after the action on the --connect given
    after it, and says so."""
    port = _free_udp_port()
    rc = main(["magcal", "status", "--connect", f"udpin:127.0.0.1:{port}", "--timeout", "1"])
    err = capsys.readouterr().err
    assert rc == 2
    assert f"ahrsd magcal: error: no ahrsd heard on udpin:127.0.0.1:{port} within 1 s" in err


def test_after_the_action_the_options_are_still_checked(capsys):
    with pytest.raises(SystemExit) as exc:
        build_parser().parse_args(["magcal", "status", "--target", "300:1"])
    assert exc.value.code == 2 and "system and component ids are 1..255" in capsys.readouterr().err
