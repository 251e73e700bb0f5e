"""`ahrsd magcal`: drive a field magnetometer recalibration of a running ahrsd from a terminal.

The same MAVLink protocol Mission Planner uses (MAV_CMD_DO_START/ACCEPT/CANCEL_MAG_CAL, MAG_CAL_PROGRESS,
MAG_CAL_REPORT, MAV_CMD_FIXED_MAG_CAL_YAW), addressed to the daemon's component, with a progress bar —
for operators without a ground station.

    ahrsd magcal start                 # turn the vehicle, watch the bar, accept at the prompt (or --accept)
    ahrsd magcal status                # what is the daemon doing
    ahrsd magcal accept | cancel
    ahrsd magcal accept-learned        # fold the iron the estimator learned into the calibration
    ahrsd magcal reset-learned         # forget the learned iron
    ahrsd magcal fixed-yaw 123.5       # the vehicle points at 123.5° TRUE: offsets from WMM, soft iron kept

--connect is a pymavlink URL; the default listens where the daemon sends by default (udpin:127.0.0.1:14550).
--target SYS:COMP defaults to the first component whose HEARTBEAT says MAV_TYPE_IMU (ahrsd: component 200).
"""

from __future__ import annotations

import argparse
import math
import sys

DEFAULT_CONNECT = "udpin:127.0.0.1:14550"
def _number_arg(lo: float = -math.inf, *, above: bool = False):
    """argparse type: a finite number >= lo (> lo with above=True); nan/inf never reach the daemon."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if not math.isfinite(value) or value < lo or (above and value == lo):
            raise argparse.ArgumentTypeError(f"expected a finite number {'>' if above else '>='} {lo:g}, got {text!r}"
                                             if math.isfinite(lo) else f"expected a finite number, got {text!r}")
        return value
    return parse


def _target_arg(text: str) -> str:
    """argparse type for --target: checked at once (exit 2 with usage), kept as the text for find_target."""
    try:
        sys_id, comp_id = (int(part) for part in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be SYS:COMP, e.g. 1:200, got {text!r}") from None
    if not (1 <= sys_id <= 255 and 1 <= comp_id <= 255):
        raise argparse.ArgumentTypeError(f"system and component ids are 1..255, got {text!r}")
    return text


def _add_link_options(parser: argparse.ArgumentParser, *, defaults: bool) -> None:
    """--connect, --target, --timeout: where the daemon is and how long to wait for it."""
    unset = argparse.SUPPRESS
    parser.add_argument("--connect", default=DEFAULT_CONNECT if defaults else unset, metavar="URL",
                        help=f"MAVLink connection (default {DEFAULT_CONNECT})")
    parser.add_argument("--target", default=None if defaults else unset, metavar="SYS:COMP", type=_target_arg,
                        help="the daemon's system and component id (default: discover)")
    parser.add_argument("--timeout", default=10.0 if defaults else unset, metavar="S",
                        type=_number_arg(0.0, above=True), help="seconds to wait for the daemon (default 10)")


def _action_parser(link: argparse.ArgumentParser):
    """The parser class of the actions: each one takes the link options too (parents=[link])."""
    def make(**kwargs) -> argparse.ArgumentParser:
        return argparse.ArgumentParser(parents=[link], **kwargs)
    return make


def register(subparsers) -> None:
    p = subparsers.add_parser("magcal", help="run a field magnetometer recalibration on a running daemon",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    _add_link_options(p, defaults=True)
    # The same options after the action (`ahrsd magcal status --timeout 2`, as a user types them): an action's
    # copy has no default, so it replaces the value given before the action only when it is given itself.
    link = argparse.ArgumentParser(add_help=False)
    _add_link_options(link, defaults=False)
    sub = p.add_subparsers(dest="action", metavar="ACTION", required=True, parser_class=_action_parser(link))
    s = sub.add_parser("start", help="start a recalibration and follow it")
    s.add_argument("--retry", action="store_true", help="restart automatically after a failed attempt")
    s.add_argument("--autosave", action="store_true", help="save a successful result without asking")
    s.add_argument("--accept", action="store_true", help="accept a successful result without asking")
    s.add_argument("--delay", type=_number_arg(0.0), default=0.0, metavar="S", help="seconds before sampling starts")
    s.add_argument("--no-wait", action="store_true", help="start and return at once")
    s.add_argument("--max-time", type=_number_arg(0.0, above=True), default=600.0, metavar="S", help="give up following after S seconds")
    sub.add_parser("accept", help="accept (save and apply) a successful result")
    sub.add_parser("cancel", help="cancel the running calibration")
    sub.add_parser("accept-learned", help="accept the iron the estimator learned (GNSS-aided ins, or mekf in turns) into the calibration")
    sub.add_parser("reset-learned", help="forget the iron the estimator learned")
    st = sub.add_parser("status", help="print progress or the last report, and the learned iron")
    st.add_argument("--seconds", type=_number_arg(0.0, above=True), default=3.0, help="how long to listen (default 3)")
    fy = sub.add_parser("fixed-yaw", help="calibrate offsets from a known TRUE heading (WMM field, soft iron kept)")
    fy.add_argument("yaw_deg", type=_number_arg(), metavar="DEG", help="true heading of the vehicle, degrees")
    fy.add_argument("--lat", type=float, default=None, metavar="DEG",
                    help="latitude of the vehicle for the WMM field (with --lon; default: the daemon's position, as its "
                    "declination: [location], else its GNSS receiver, else the autopilot's)")
    fy.add_argument("--lon", type=float, default=None, metavar="DEG", help="longitude (with --lat)")
    p.set_defaults(func=run)


def _fixed_yaw_position(args) -> tuple[float, float]:
    """(lat, lon) for MAV_CMD_FIXED_MAG_CAL_YAW p3/p4; (0, 0) asks the daemon for its own position.

    Raises ValueError for one of the two alone (the daemon would silently use 0 for the other) or out of range.
    """
    lat, lon = args.lat, args.lon
    if lat is None and lon is None:
        return 0.0, 0.0
    if lat is None or lon is None:
        raise ValueError("give --lat and --lon together")
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        raise ValueError(f"position {lat}, {lon} out of range (latitude ±90, longitude ±180)")
    return lat, lon


def run(args) -> int:
    from ahrsd.cli.magcal_client import (CLIENT_COMPONENT, CLIENT_SYSTEM, MAV_CMD_DO_CANCEL_MAG_CAL,
                                         MAV_CMD_FIXED_MAG_CAL_YAW, MagCalClient)
    from ahrsd.daemon.mavlink_io import mavutil  # sets MAVLink 2 + ardupilotmega before pymavlink loads

    if args.action == "fixed-yaw":
        try:
            position = _fixed_yaw_position(args)
        except ValueError as exc:
            print(f"ahrsd magcal fixed-yaw: error: {exc}", file=sys.stderr)
            return 2

    try:
        conn = mavutil.mavlink_connection(args.connect, source_system=CLIENT_SYSTEM,
                                          source_component=CLIENT_COMPONENT, autoreconnect=True)
    except Exception as exc:  # noqa: BLE001 - a bad URL or port is the operator's to fix
        print(f"ahrsd magcal: error: cannot open {args.connect}: {exc}", file=sys.stderr)
        return 2
    client = MagCalClient(conn, args.timeout)
    try:
        if not client.find_target(args.target):
            print(f"ahrsd magcal: error: no ahrsd heard on {args.connect} within {args.timeout:.0f} s "
                  "(check --connect, or give --target SYS:COMP)", file=sys.stderr)
            return 2
        if args.action == "start":
            return client.start(retry=args.retry, autosave=args.autosave, delay_s=args.delay, wait=not args.no_wait,
                                max_time_s=args.max_time, accept=args.accept)
        if args.action == "accept":
            return client.accept()
        if args.action == "cancel":
            return client.simple(MAV_CMD_DO_CANCEL_MAG_CAL, "cancel")
        if args.action == "status":
            return client.status(args.seconds)
        if args.action in ("accept-learned", "reset-learned"):
            from ahrsd.daemon.learned_iron import ACTION_ACCEPT, ACTION_RESET, CMD_LEARNED_IRON

            action = ACTION_ACCEPT if args.action == "accept-learned" else ACTION_RESET
            return client.simple(CMD_LEARNED_IRON, args.action, action)
        if args.action == "fixed-yaw":
            return client.simple(MAV_CMD_FIXED_MAG_CAL_YAW, f"fixed-yaw {args.yaw_deg:.1f} deg", args.yaw_deg, 0,
                                 *position)
        return 2
    finally:
        conn.close()
