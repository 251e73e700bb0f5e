"""A ground station for the daemon's mag-cal sessions over UDP (tests/test_magcal_integration.py,
test_magcal_field_daemon.py): pymavlink on a udpin socket that keeps what it received, sends COMMAND_LONG and
waits for its ACK, plays the armed or disarmed autopilot's HEARTBEAT, and reads the calibrated field's norm."""

from __future__ import annotations

import collections
import time

import numpy as np

from ahrsd.daemon.mavlink_io import mavlink, mavutil

REPLY_LIMIT_S = 15.0     # a reply (ACK, STATUSTEXT, the first MAG_CAL_PROGRESS) comes at once; 15 s: a loaded machine
STARTING_LIMIT_S = 240.0  # a daemon's first HEARTBEAT: imports and, on a cold cache (a run without -n), the estimator's compile


class Client:
    def __init__(self, port: int):
        self.conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255, source_component=190)
        self.msgs: list = []

    def wait(self, pred, timeout: float):
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            m = self.conn.recv_match(blocking=True, timeout=0.2)
            if m is None or m.get_type() == "BAD_DATA":
                continue
            self.msgs.append(m)
            if pred(m):
                return m
        return None

    def drop_queued(self) -> int:
        """Read and drop every message already waiting in the socket; how many."""
        dropped = 0
        while self.conn.recv_match(blocking=False) is not None:
            dropped += 1
        return dropped

    def seen_or_wait(self, pred, timeout: float, since: int = 0):
        """A message already received (after index `since`) matching pred, else wait for one."""
        for m in self.msgs[since:]:
            if pred(m):
                return m
        return self.wait(pred, timeout)

    def of(self, kind: str, since: int = 0) -> list:
        return [m for m in self.msgs[since:] if m.get_type() == kind]

    def command(self, command: int, *params: float, target=(1, 200), timeout: float = REPLY_LIMIT_S,
                resend_every_s: float | None = None):
        """Send COMMAND_LONG and wait for its ACK. With `resend_every_s`, send it again (confirmation + 1) each
        time that long passes without an ACK, as the MAVLink command protocol has a ground station do
        (https://mavlink.io/en/services/command.html): only for a command the daemon answers the same when it
        comes twice (DO_ACCEPT_MAG_CAL: "saved already")."""
        p = list(params) + [0.0] * (7 - len(params))
        is_ack = lambda m: m.get_type() == "COMMAND_ACK" and m.command == command  # noqa: E731
        end = time.monotonic() + timeout
        confirmation = 0
        while True:
            self.conn.mav.command_long_send(target[0], target[1], command, confirmation, *p)
            left_s = end - time.monotonic()
            ack = self.wait(is_ack, left_s if resend_every_s is None else min(resend_every_s, left_s))
            if ack is not None or resend_every_s is None or time.monotonic() >= end:
                return ack
            confirmation = min(confirmation + 1, 255)

    def accept_calibration(self):
        """DO_ACCEPT_MAG_CAL and its ACK, sent again every third of REPLY_LIMIT_S without one (the daemon answers a
        repeated accept the same: its duplicate window's ACK, then "saved already"), for up to twice that limit: a
        loaded machine lost the first one's ACK."""
        return self.command(42425, timeout=2 * REPLY_LIMIT_S, resend_every_s=REPLY_LIMIT_S / 3)

    def autopilot_heartbeat(self, armed: bool) -> None:
        mav = self.conn.mav
        mav.srcSystem, mav.srcComponent = 1, 1
        mav.heartbeat_send(mavlink.MAV_TYPE_SURFACE_BOAT, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                           mavlink.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0, 0, mavlink.MAV_STATE_STANDBY)
        mav.srcSystem, mav.srcComponent = 255, 190

    def mag_norm_spread_ut(self, seconds: float) -> tuple[float, float]:
        """Mean and std of |calibrated mag| from HIGHRES_IMU (gauss) over `seconds`."""
        start = len(self.msgs)
        self.wait(lambda m: False, seconds)
        for _ in range(3):  # a loaded machine can starve the daemon for a while: wait longer, not fail
            if len(self.of("HIGHRES_IMU", start)) > 5:
                break
            self.wait(lambda m: False, seconds)
        norms = [100.0 * np.linalg.norm([m.xmag, m.ymag, m.zmag]) for m in self.of("HIGHRES_IMU", start)]
        assert len(norms) > 5, f"no HIGHRES_IMU from the daemon: {collections.Counter(m.get_type() for m in self.msgs[start:])}"
        return float(np.mean(norms)), float(np.std(norms))
