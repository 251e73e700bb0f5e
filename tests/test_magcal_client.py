"""`ahrsd magcal` client pieces that need no daemon: argument parsing, chunked STATUSTEXT, the progress bar."""

from __future__ import annotations

import io
from types import SimpleNamespace

from ahrsd.cli.main import build_parser
from ahrsd.cli.magcal_client import MagCalClient
from ahrsd.daemon.magcal import statustext_chunks
from ahrsd.daemon.mavlink_io import mavlink

MAV = mavlink.MAVLink(None, srcSystem=1, srcComponent=200)


def wire(msg):
    return mavlink.MAVLink(None).parse_char(bytearray(msg.pack(MAV)))


def test_parser_has_magcal_actions():
    args = build_parser().parse_args(["magcal", "--target", "1:200", "start", "--accept", "--delay", "2"])
    assert args.action == "start" and args.accept and args.delay == 2.0 and args.target == "1:200"
    args = build_parser().parse_args(["magcal", "fixed-yaw", "123.5"])
    assert args.action == "fixed-yaw" and args.yaw_deg == 123.5


def test_client_reassembles_chunked_statustext_and_draws_bar():
    out = io.StringIO()
    client = MagCalClient(conn=None, timeout_s=1.0, out=out)
    text = "tilt range too small for full model: fitted offsets only"
    for m in statustext_chunks(4, text, 9):
        client._show(wire(m))
    assert f"[ahrsd] {text}\n" in out.getvalue()
    prog = wire(mavlink.MAVLink_mag_cal_progress_message(0, 1, 2, 1, 40, [255, 1] + [0] * 8, 0.7, 0.7, 0.0))
    client._show(prog)
    assert "40%" in out.getvalue() and "cells  9/80" in out.getvalue() and "turn right" in out.getvalue()


def test_find_target_rejects_bad_target_text():
    client = MagCalClient(conn=SimpleNamespace(), timeout_s=0.1, out=io.StringIO())
    assert client.find_target("nonsense") is False
