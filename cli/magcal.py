"""`ahrsd magcal`: drive a field magnetometer recalibration of a running ahrsd from a terminal.

The same MAVLink protocol Mission Planner uses (MAV_CMD_DO_START/ACCEPT/CANCEL_MAG_CAL, MAG_CAL_PROGRESS,
MAG_CAL_REPORT, MAV_CMD_FIXED_MAG_CAL_YAW), addressed to the daemon's component, with a progress bar —
for operators without a ground station.

    ahrsd magcal start                 # turn the vehicle, watch the bar, accept at the prompt (or --accept)
    ahrsd magcal status                # what is the daemon doing
    ahrsd magcal accept | cancel
    ahrsd magcal fixed-yaw 123.5       # the vehicle points at 123.5° TRUE: offsets from WMM, soft iron kept

--connect is a pymavlink URL; the default listens where the daemon sends by default (udpin:127.0.0.1:14550).
--target SYS:COMP defaults to the first component whose HEARTBEAT says MAV_TYPE_IMU (ahrsd: component 200).
"""

from __future__ import annotations

import argparse
import math
import sys
import time

DEFAULT_CONNECT = "udpin:127.0.0.1:14550"
CLIENT_SYSTEM, CLIENT_COMPONENT = 255, 190   # a ground station (MAV_COMP_ID_MISSIONPLANNER)
MAV_TYPE_IMU = 40
MAV_COMP_ID_IMU = 200
STATUS_NAMES = {0: "not started", 1: "waiting to start", 2: "step 1", 3: "step 2", 4: "SUCCESS", 5: "FAILED",
                6: "FAILED (orientation)", 7: "FAILED (radius)", 8: "FAILED (offsets)", 9: "FAILED (diagonals)",
                10: "FAILED (residuals high)"}
RESULT_NAMES = {0: "ACCEPTED", 1: "TEMPORARILY_REJECTED", 2: "DENIED", 3: "UNSUPPORTED", 4: "FAILED",
                5: "IN_PROGRESS"}


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


def register(subparsers) -> None:
    p = subparsers.add_parser("magcal", help="run a field magnetometer recalibration on a running daemon",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--connect", default=DEFAULT_CONNECT, metavar="URL", help=f"MAVLink connection (default {DEFAULT_CONNECT})")
    p.add_argument("--target", metavar="SYS:COMP", type=_target_arg, help="the daemon's system and component id (default: discover)")
    p.add_argument("--timeout", type=_number_arg(0.0, above=True), default=10.0, metavar="S", help="seconds to wait for the daemon (default 10)")
    sub = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    s = sub.add_parser("start", help="start a recalibration and follow it")
    s.add_argument("--retry", action="store_true", help="restart automatically after a failed attempt")
    s.add_argument("--autosave", action="store_true", help="save a successful result without asking")
    s.add_argument("--accept", action="store_true", help="accept a successful result without asking")
    s.add_argument("--delay", type=_number_arg(0.0), default=0.0, metavar="S", help="seconds before sampling starts")
    s.add_argument("--no-wait", action="store_true", help="start and return at once")
    s.add_argument("--max-time", type=_number_arg(0.0, above=True), default=600.0, metavar="S", help="give up following after S seconds")
    sub.add_parser("accept", help="accept (save and apply) a successful result")
    sub.add_parser("cancel", help="cancel the running calibration")
    st = sub.add_parser("status", help="print progress or the last report")
    st.add_argument("--seconds", type=_number_arg(0.0, above=True), default=3.0, help="how long to listen (default 3)")
    fy = sub.add_parser("fixed-yaw", help="calibrate offsets from a known TRUE heading (WMM field, soft iron kept)")
    fy.add_argument("yaw_deg", type=_number_arg(), metavar="DEG", help="true heading of the vehicle, degrees")
    fy.add_argument("--lat", type=float, default=None, metavar="DEG",
                    help="latitude of the vehicle for the WMM field (with --lon; default: the autopilot's position, "
                    "else the daemon's [location])")
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
    from ahrsd.daemon.mavlink_io import mavutil  # sets MAVLink 2 + ardupilotmega before pymavlink loads

    if args.action == "fixed-yaw":
        try:
            position = _fixed_yaw_position(args)
        except ValueError as exc:
            print(f"ahrsd magcal fixed-yaw: {exc}", file=sys.stderr)
            return 2

    try:
        conn = mavutil.mavlink_connection(args.connect, source_system=CLIENT_SYSTEM,
                                          source_component=CLIENT_COMPONENT, autoreconnect=True)
    except Exception as exc:  # noqa: BLE001 - a bad URL or port is the operator's to fix
        print(f"cannot open {args.connect}: {exc}", file=sys.stderr)
        return 2
    client = MagCalClient(conn, args.timeout)
    try:
        if not client.find_target(args.target):
            print(f"no ahrsd heard on {args.connect} within {args.timeout:.0f} s "
                  "(check --connect, or give --target SYS:COMP)", file=sys.stderr)
            return 2
        if args.action == "start":
            return client.start(args)
        if args.action == "accept":
            return client.simple(42425, "accept")
        if args.action == "cancel":
            return client.simple(42426, "cancel")
        if args.action == "status":
            return client.status(args.seconds)
        if args.action == "fixed-yaw":
            return client.simple(42006, f"fixed-yaw {args.yaw_deg:.1f} deg", args.yaw_deg, 0, *position)
        return 2
    finally:
        conn.close()


class MagCalClient:
    def __init__(self, conn, timeout_s: float, out=sys.stdout):
        self.conn = conn
        self.timeout_s = timeout_s
        self.out = out
        self.sys = self.comp = None
        self._bar_shown = False
        self._chunks: dict[int, dict[int, str]] = {}

    # ------------------------------------------------------------------ plumbing
    def find_target(self, target: str | None) -> bool:
        if target:
            try:
                sys_s, comp_s = target.split(":")
                self.sys, self.comp = int(sys_s), int(comp_s)
            except ValueError:
                print(f"--target must be SYS:COMP, got {target!r}", file=sys.stderr)
                return False
        deadline = time.monotonic() + self.timeout_s
        while time.monotonic() < deadline:
            # heartbeats also open a udpout link and tell the daemon where we are
            self.conn.mav.heartbeat_send(6, 8, 0, 0, 0)  # MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID
            m = self.conn.recv_match(type="HEARTBEAT", blocking=True, timeout=1.0)
            if m is None:
                continue
            if self.sys is not None:
                if (m.get_srcSystem(), m.get_srcComponent()) == (self.sys, self.comp):
                    return True
                continue
            if m.type == MAV_TYPE_IMU or m.get_srcComponent() == MAV_COMP_ID_IMU:
                self.sys, self.comp = m.get_srcSystem(), m.get_srcComponent()
                self._print(f"ahrsd found: system {self.sys}, component {self.comp}")
                return True
        return False

    def _from_target(self, m) -> bool:
        return (m.get_srcSystem(), m.get_srcComponent()) == (self.sys, self.comp)

    def command(self, command: int, *params: float) -> int | None:
        """COMMAND_LONG to the daemon, re-sent (confirmation 1, 2) when no ACK arrives within 1.5 s."""
        p = list(params) + [0.0] * (7 - len(params))
        for confirmation in range(3):
            self.conn.mav.command_long_send(self.sys, self.comp, command, confirmation, *p)
            deadline = time.monotonic() + 1.5
            while time.monotonic() < deadline:
                m = self.conn.recv_match(blocking=True, timeout=0.2)
                if m is None:
                    continue
                if not self._from_target(m):
                    continue
                if m.get_type() == "COMMAND_ACK" and m.command == command:
                    return int(m.result)
                self._show(m)
        return None

    def simple(self, command: int, what: str, *params: float) -> int:
        result = self.command(command, *params)
        if result is None:
            self._print(f"{what}: no answer from the daemon")
            return 1
        self._drain(1.0)
        self._print(f"{what}: {RESULT_NAMES.get(result, result)}")
        return 0 if result == 0 else 1

    def _drain(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            m = self.conn.recv_match(blocking=True, timeout=0.1)
            if m is not None and self._from_target(m):
                self._show(m)

    # ------------------------------------------------------------------ display
    def _print(self, text: str) -> None:
        if self._bar_shown:
            self.out.write("\n")
            self._bar_shown = False
        self.out.write(text + "\n")
        self.out.flush()

    def _show(self, m) -> None:
        kind = m.get_type()
        if kind == "STATUSTEXT":
            text = self._statustext(m)
            if text is not None:
                self._print(f"[ahrsd] {text}")
        elif kind == "MAG_CAL_PROGRESS":
            self._bar(m)

    def _statustext(self, m) -> str | None:
        """The whole text of a STATUSTEXT, reassembling MAVLink 2 chunks (id != 0); None until complete."""
        chunk_id = getattr(m, "id", 0)
        if not chunk_id:
            return m.text
        parts = self._chunks.setdefault(chunk_id, {})
        parts[getattr(m, "chunk_seq", 0)] = m.text
        if len(m.text.encode("utf-8", "replace")) < 50:   # the last chunk is shorter than the field
            del self._chunks[chunk_id]
            return "".join(parts[k] for k in sorted(parts))
        return None

    def _bar(self, m) -> None:
        width = 30
        filled = int(width * m.completion_pct / 100)
        cells = sum(bin(b).count("1") for b in m.completion_mask)
        hint = ""
        if abs(m.direction_y) > 0.1 and m.direction_z == 0:
            hint = "turn right" if m.direction_y > 0 else "turn left"
        line = (f"\r[{'#' * filled}{'.' * (width - filled)}] {m.completion_pct:3d}% "
                f"{STATUS_NAMES.get(m.cal_status, m.cal_status):<16} attempt {m.attempt} cells {cells:2d}/80 {hint:<10}")
        self.out.write(line)
        self.out.flush()
        self._bar_shown = True

    def _report(self, r) -> None:
        self._print(
            f"result: {STATUS_NAMES.get(r.cal_status, r.cal_status)}  fitness {r.fitness:.1f} mG  "
            f"{'saved' if r.autosaved else 'not saved'}\n"
            f"  offsets  {r.ofs_x:8.1f} {r.ofs_y:8.1f} {r.ofs_z:8.1f} mG\n"
            f"  diag     {r.diag_x:8.4f} {r.diag_y:8.4f} {r.diag_z:8.4f}\n"
            f"  offdiag  {r.offdiag_x:8.4f} {r.offdiag_y:8.4f} {r.offdiag_z:8.4f}")

    # ------------------------------------------------------------------ actions
    def start(self, args) -> int:
        result = self.command(42424, 0, float(args.retry), float(args.autosave), float(args.delay), 0)
        if result is None:
            self._print("start: no answer from the daemon")
            return 1
        if result != 0:
            self._drain(0.5)
            self._print(f"start: {RESULT_NAMES.get(result, result)}")
            return 1
        self._print("calibration started: turn the vehicle slowly through 360 deg (Ctrl-C cancels)")
        if args.no_wait:
            return 0
        deadline = time.monotonic() + args.max_time
        try:
            while time.monotonic() < deadline:
                m = self.conn.recv_match(blocking=True, timeout=0.5)
                if m is None or not self._from_target(m):
                    continue
                if m.get_type() != "MAG_CAL_REPORT":
                    self._show(m)
                    continue
                self._report(m)
                if m.cal_status != 4:
                    self.command(42426, 0)  # stop the re-sent reports
                    return 1
                if m.autosaved:
                    return 0
                if not args.accept and not _ask("accept and save this calibration? [y/N] "):
                    self.command(42426, 0)
                    self._print("not accepted: calibration unchanged")
                    return 1
                return self.simple(42425, "accept", 0)
        except KeyboardInterrupt:
            self._print("cancelling...")
            self.command(42426, 0)
            return 130
        self._print("gave up waiting (--max-time); the calibration is still running on the daemon")
        return 1

    def status(self, seconds: float) -> int:
        end = time.monotonic() + seconds
        seen = False
        while time.monotonic() < end:
            m = self.conn.recv_match(blocking=True, timeout=0.2)
            if m is None or not self._from_target(m):
                continue
            if m.get_type() == "MAG_CAL_REPORT":
                self._report(m)
                return 0
            if m.get_type() in ("MAG_CAL_PROGRESS", "STATUSTEXT"):
                seen = True
                self._show(m)
        if not seen:
            self._print("no calibration running")
        else:
            self._print("")
        return 0


def _ask(prompt: str) -> bool:
    if not sys.stdin.isatty():
        return False
    try:
        return input("\n" + prompt).strip().lower() in ("y", "yes")
    except EOFError:
        return False
