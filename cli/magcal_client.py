"""A ground-station client of the magnetometer-calibration protocol, as `ahrsd magcal` uses it.

MAV_CMD_DO_START/ACCEPT/CANCEL_MAG_CAL and MAV_CMD_FIXED_MAG_CAL_YAW as COMMAND_LONG to the daemon's
component, MAG_CAL_PROGRESS drawn as a progress bar, MAG_CAL_REPORT printed, STATUSTEXT (MAVLink 2 chunks
reassembled) shown. It needs only a pymavlink connection to a running ahrsd, never the service itself.
"""

from __future__ import annotations

import sys
import threading
import time
from typing import Callable

CLIENT_SYSTEM, CLIENT_COMPONENT = 255, 190   # a ground station (MAV_COMP_ID_MISSIONPLANNER)
MAV_TYPE_IMU = 40
MAV_COMP_ID_IMU = 200
STATUS_NAMES = {0: "not started", 1: "waiting to start", 2: "step 1", 3: "step 2", 4: "SUCCESS", 5: "FAILED",
                6: "FAILED (orientation)", 7: "FAILED (radius)", 8: "FAILED (offsets)", 9: "FAILED (diagonals)",
                10: "FAILED (residuals high)"}
RESULT_NAMES = {0: "ACCEPTED", 1: "TEMPORARILY_REJECTED", 2: "DENIED", 3: "UNSUPPORTED", 4: "FAILED",
                5: "IN_PROGRESS"}
# MAV_CMD ids: ardupilotmega.xml (DO_*_MAG_CAL) and common.xml (FIXED_MAG_CAL_YAW)
MAV_CMD_DO_START_MAG_CAL = 42424
MAV_CMD_DO_ACCEPT_MAG_CAL = 42425
MAV_CMD_DO_CANCEL_MAG_CAL = 42426
MAV_CMD_FIXED_MAG_CAL_YAW = 42006
MAG_CAL_SUCCESS = 4
REPORT_GONE_S = 5.0     # a finished session's MAG_CAL_REPORT comes at 1 Hz (daemon.magcal) until it is settled
REPORT_WAIT_S = 2.5     # `accept` listens this long for that report (or a running session's progress) first


class MagCalClient:
    """One session with one daemon: `find_target`, then an action (`start`, `simple`, `status`) whose exit
    status it returns; progress and results are written to `out` for a person."""

    def __init__(self, conn, timeout_s: float, out=sys.stdout, ask: Callable[[str], bool] | None = None):
        self.conn = conn
        self.timeout_s = timeout_s
        self.out = out
        # the operator's yes/no at a prompt (the terminal's by default); None when nobody can answer there
        self.ask = ask or _ask
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
            for m in self._target_messages(time.monotonic() + 1.5, poll_s=0.2):
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

    def accept(self, listen_s: float = REPORT_WAIT_S) -> int:
        """`ahrsd magcal accept`: accept the finished calibration that waits on the daemon. The daemon's ACK alone
        cannot say whether anything was saved: an accept sent again after a save is ACCEPTED (ArduPilot's rule,
        which MAVProxy's accept on every report and a client's re-sent accept rely on). So first listen for what
        waits: a finished session's MAG_CAL_REPORT (1 Hz until settled) or a running one's progress; with
        neither, nothing is sent and the exit status is 1."""
        for m in self._target_messages(time.monotonic() + listen_s, poll_s=0.2):
            kind = m.get_type()
            if kind == "MAG_CAL_REPORT" and m.cal_status == MAG_CAL_SUCCESS and m.autosaved:
                self._print("nothing to accept: the calibration was saved already (autosave or an earlier accept)")
                return 1
            if kind in ("MAG_CAL_REPORT", "MAG_CAL_PROGRESS"):
                return self.simple(MAV_CMD_DO_ACCEPT_MAG_CAL, "accept")
            self._show(m)
        self._print("nothing to accept: no calibration waiting (none finished, or it was already saved or "
                    "cancelled; `ahrsd magcal status` shows what the daemon is doing)")
        return 1

    def _drain(self, seconds: float) -> None:
        for m in self._target_messages(time.monotonic() + seconds, poll_s=0.1):
            self._show(m)

    def _target_messages(self, deadline: float, poll_s: float):
        """The target's messages as they arrive (others dropped) until `deadline` (time.monotonic), each wait for
        one at most `poll_s`."""
        while time.monotonic() < deadline:
            m = self.conn.recv_match(blocking=True, timeout=poll_s)
            if m is not None and self._from_target(m):
                yield m

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
                # the daemon's own texts start "ahrsd: " (for a ground station's mixed log); here every line
                # is the daemon's, already marked
                self._print(f"[ahrsd] {text.removeprefix('ahrsd: ')}")
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
        level = m.direction_z == 0     # the daemon asks a level vehicle only to turn, never to tilt
        if abs(m.direction_y) > 0.1 and level:
            hint = "turn right" if m.direction_y > 0 else "turn left"
        # the 80 sphere cells are ArduPilot's tumble coverage: a level vehicle never fills them, so only the
        # completion (the daemon's, for the model its data supports) is shown for it
        sphere = "" if level else f"cells {cells:2d}/80 "
        line = (f"\r[{'#' * filled}{'.' * (width - filled)}] {m.completion_pct:3d}% "
                f"{STATUS_NAMES.get(m.cal_status, m.cal_status):<16} attempt {m.attempt} {sphere}{hint:<10}")
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
    def start(self, *, retry: bool = False, autosave: bool = False, delay_s: float = 0.0, wait: bool = True,
              max_time_s: float = 600.0, accept: bool = False) -> int:
        """Start a calibration; unless wait is False follow it to its report (at most max_time_s) and accept a
        success when `accept`, else after asking on the terminal."""
        result = self.command(MAV_CMD_DO_START_MAG_CAL, 0, float(retry), float(autosave), float(delay_s), 0)
        if result is None:
            self._print("start: no answer from the daemon")
            return 1
        if result != 0:
            self._drain(0.5)
            self._print(f"start: {RESULT_NAMES.get(result, result)}")
            return 1
        self._print("calibration started: turn the vehicle slowly through 360 deg (Ctrl-C cancels)")
        if not wait:
            return 0
        deadline = time.monotonic() + max_time_s
        try:
            report = self._next_report(deadline)
            if report is not None:
                return self._answer_report(report, accept, deadline)
        except KeyboardInterrupt:
            self._print("cancelling...")
            self.command(MAV_CMD_DO_CANCEL_MAG_CAL, 0)
            return 130
        self._print("gave up waiting (--max-time); the calibration is still running on the daemon")
        return 1

    def _next_report(self, deadline: float):
        """The target's next MAG_CAL_REPORT (its other messages shown meanwhile: progress, STATUSTEXT), or None at
        `deadline` (time.monotonic)."""
        for m in self._target_messages(deadline, poll_s=0.5):
            if m.get_type() != "MAG_CAL_REPORT":
                self._show(m)
                continue
            return m
        return None

    def _answer_report(self, m, accept: bool, deadline: float) -> int:
        """Show the report and settle it: a failure cancelled, an autosaved one done, else accepted when `accept`
        or the terminal says yes (cancelled on no); settled elsewhere (another ground station) or by nobody
        (no terminal), as that says. The exit status."""
        self._report(m)
        if m.cal_status != MAG_CAL_SUCCESS:
            self.command(MAV_CMD_DO_CANCEL_MAG_CAL, 0)  # stop the re-sent reports
            return 1
        if m.autosaved:
            return 0
        answer, elsewhere = (True, None) if accept else self._ask_listening("accept and save this calibration? [y/N] ")
        elsewhere = elsewhere or self._settled_elsewhere()
        if elsewhere is not None:
            return self._settled(elsewhere)
        if answer is None:
            return self._await_decision_elsewhere(deadline)
        if not answer:
            self.command(MAV_CMD_DO_CANCEL_MAG_CAL, 0)
            self._print("not accepted: calibration unchanged")
            return 1
        return self.simple(MAV_CMD_DO_ACCEPT_MAG_CAL, "accept", 0)

    def _await_decision_elsewhere(self, deadline: float) -> int:
        """Nobody can answer the prompt (stdin is not a terminal, or at its end): the decision is not ours, so
        the session is left waiting on the daemon and followed until another terminal or ground station accepts
        or cancels it (#30: a client at EOF cancelled it, and the accept that came later saved nothing)."""
        self._print("no answer possible here (stdin is not a terminal or at its end): the result waits on the "
                    "daemon; accept it with `ahrsd magcal accept` or drop it with `ahrsd magcal cancel`")
        last_report = time.monotonic()
        for m in self._target_messages(deadline, poll_s=0.5):
            if m.get_type() == "MAG_CAL_REPORT":
                last_report = time.monotonic()
                continue                    # the report repeats at 1 Hz until the session is settled
            if time.monotonic() - last_report > REPORT_GONE_S:
                # settled while this terminal heard nothing: a second `ahrsd magcal` on this computer binds the
                # same UDP port, and while it runs the kernel hands the daemon's datagrams to it alone
                return self._settled("gone")
            if m.get_type() != "STATUSTEXT":
                self._show(m)
                continue
            text = self._statustext(m)
            if text is None:
                continue                    # a chunk of a longer text
            self._print(f"[ahrsd] {text.removeprefix('ahrsd: ')}")
            if _settled_by(text) is not None:
                return self._settled(_settled_by(text))
        self._print("gave up waiting (--max-time); the result still waits on the daemon")
        return 1

    def _settled(self, how: str) -> int:
        """Say how another ground station or terminal settled the session ("saved", "cancelled", or "gone":
        settled, but this terminal did not hear how): exit 0 when the calibration was saved."""
        if how == "saved":
            self._print("accepted from another ground station or terminal: calibration saved")
            return 0
        if how == "gone":
            self._print("the daemon no longer reports this result: it was accepted or cancelled elsewhere "
                        "while this terminal heard nothing (the other `ahrsd magcal` or ground station got "
                        "the daemon's answer); nothing sent from here")
            return 1
        self._print("cancelled from another ground station or terminal: calibration unchanged")
        return 1

    def _ask_listening(self, prompt: str) -> tuple[bool | None, str | None]:
        """Ask on the terminal while a thread keeps reading the link: (the operator's answer, "saved" or
        "cancelled" when the daemon said the session was settled elsewhere while the prompt waited, "gone" when
        it said nothing but its report stopped while its other messages went on). Unread, the link's receive
        buffer fills with the daemon's streams within seconds and the kernel drops what comes after, the one
        STATUSTEXT that says another ground station accepted included. The report stopping is the only news
        when the settling came from a second `ahrsd magcal` on this computer: it binds the same UDP port and,
        while it runs, the kernel hands the daemon's datagrams to it alone (#30 item 12, walked: "not
        accepted: calibration unchanged" after `ahrsd magcal accept` had saved it)."""
        stop = threading.Event()
        settled: list[str] = []
        last_report = time.monotonic()      # the report that brought us to the prompt
        gone = False

        def listen() -> None:
            nonlocal last_report, gone
            while not stop.is_set():
                m = self.conn.recv_match(blocking=True, timeout=0.1)
                if m is None or not self._from_target(m):
                    continue
                if m.get_type() == "MAG_CAL_REPORT":
                    last_report = time.monotonic()
                    continue
                what = self._settle_news(m)
                if what is not None:
                    settled.append(what)
                elif time.monotonic() - last_report > REPORT_GONE_S:
                    gone = True                 # the daemon talks on, but its report (1 Hz until settled) stopped

        reader = threading.Thread(target=listen, name="magcal-listen", daemon=True)
        reader.start()
        try:
            answer = self.ask(prompt)
        finally:
            stop.set()
            reader.join()
        # what the daemon said beats what we inferred
        return answer, (settled[-1] if settled else "gone" if gone else None)

    def _settle_news(self, m) -> str | None:
        """"saved" or "cancelled" when `m` is the daemon's STATUSTEXT saying so (its last chunk), else None."""
        if m is None or not self._from_target(m) or m.get_type() != "STATUSTEXT":
            return None
        return _settled_by(self._statustext(m) or "")

    def _settled_elsewhere(self, listen_s: float = 0.5) -> str | None:
        """"saved" or "cancelled" when the daemon said so (STATUSTEXT) in the messages still queued, or within
        `listen_s` more; None when the session is still waiting for an answer."""
        end = time.monotonic() + listen_s
        while True:
            m = self.conn.recv_match(blocking=False)
            if m is None:
                if time.monotonic() >= end:
                    return None
                time.sleep(0.02)
                continue
            what = self._settle_news(m)
            if what is not None:
                return what

    def status(self, seconds: float) -> int:
        """The running calibration (progress) or its last report, then the learned iron."""
        seen = False
        for m in self._target_messages(time.monotonic() + seconds, poll_s=0.2):
            if m.get_type() == "MAG_CAL_REPORT":
                self._report(m)
                seen = True
                break
            if m.get_type() in ("MAG_CAL_PROGRESS", "STATUSTEXT"):
                seen = True
                self._show(m)
        if not seen:
            self._print("no calibration running")
        self._print(self.learned_iron_text())
        return 0

    def learned_iron(self, timeout_s: float = 2.0) -> dict[str, float]:
        """The daemon's read-only MAG_LRN_* parameters (daemon.learned_iron: hard iron and soft iron), by
        PARAM_REQUEST_READ; a daemon that does not know a name leaves it out."""
        from ahrsd.daemon.learned_iron import PARAM_NAMES, SOFT_PARAM_NAMES, SOFT_SD_PARAM, SOURCE_PARAM

        names = (*PARAM_NAMES, *SOFT_PARAM_NAMES, SOFT_SD_PARAM, SOURCE_PARAM)
        for name in names:
            self.conn.mav.param_request_read_send(self.sys, self.comp, name.encode("ascii"), -1)
        values: dict[str, float] = {}
        deadline = time.monotonic() + timeout_s
        while len(values) < len(names) and time.monotonic() < deadline:
            m = self.conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.2)
            if m is None or not self._from_target(m):
                continue
            name = m.param_id if isinstance(m.param_id, str) else m.param_id.decode("ascii", "replace")
            name = name.split("\0", 1)[0]
            if name in names:
                values[name] = float(m.param_value)
        return values

    def learned_iron_text(self) -> str:
        from ahrsd.daemon.learned_iron import (NOT_LEARNING_SD, PARAM_NAMES, SOFT_PARAM_NAMES, SOFT_SD_PARAM,
                                               SOURCE_CODES, SOURCE_PARAM)

        v = self.learned_iron(min(2.0, self.timeout_s))
        if not all(n in v for n in PARAM_NAMES):
            return "learned iron: not reported (an older ahrsd?)"
        if v[PARAM_NAMES[3]] <= NOT_LEARNING_SD:
            return "learned iron: none (the estimator learns none: run mekf or the GNSS-aided ins)"
        if SOURCE_PARAM in v and v[SOURCE_PARAM] == 0:
            # the daemon publishes source 0 until its estimator learned something; accept-learned would be refused
            return ("learned iron: nothing learned yet (the GNSS-aided ins learns it while GNSS holds the heading, "
                    "mekf in turns once it finds the calibration wrong)")
        x, y, z = (v[n] for n in PARAM_NAMES[:3])
        source = {code: name for name, code in SOURCE_CODES.items()}.get(int(v.get(SOURCE_PARAM, -1)))
        lines = [f"learned iron (body FRD, on top of the calibration): hard {x:+.2f} {y:+.2f} {z:+.2f} uT, "
                 f"1-sigma up to {v[PARAM_NAMES[3]]:.2f} uT"
                 + (f" (source: {source})" if source is not None else "")]
        if all(n in v for n in (*SOFT_PARAM_NAMES, SOFT_SD_PARAM)):
            rows = ["[" + " ".join(f"{v[n]:+.4f}" for n in SOFT_PARAM_NAMES[3 * r:3 * r + 3]) + "]" for r in range(3)]
            sd = v[SOFT_SD_PARAM]
            lines.append(f"  soft iron I + D: {' '.join(rows)}"
                         + (f", 1-sigma up to {sd:.4f}" if sd > NOT_LEARNING_SD else ", none learned"))
        else:
            lines.append("  soft iron: not reported (an older ahrsd?)")
        lines.append("  keep it: ahrsd magcal accept-learned   forget it: ahrsd magcal reset-learned")
        return "\n".join(lines)


def _settled_by(text: str) -> str | None:
    """"saved" or "cancelled" when the daemon's STATUSTEXT says the session was settled (daemon.magcal)."""
    if text.startswith("Mag cal saved"):
        return "saved"
    if text.startswith("Mag cal cancelled"):
        return "cancelled"
    return None


def _ask(prompt: str) -> bool | None:
    """The terminal's yes (True) or no (False, the default on an empty line); None when there is nobody to
    ask: stdin is not a terminal, or it ended (Ctrl-D, /dev/null)."""
    if not sys.stdin.isatty():
        return None
    try:
        return input("\n" + prompt).strip().lower() in ("y", "yes")
    except EOFError:
        return None
