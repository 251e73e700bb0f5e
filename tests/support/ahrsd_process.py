"""`ahrsd run` as a subprocess on the simulated chip, with a pymavlink ground station on loopback."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

os.environ["MAVLINK20"] = "1"
os.environ["MAVLINK_DIALECT"] = "ardupilotmega"
from pymavlink import mavutil  # noqa: E402

from ahrsd.daemon.mavlink_io import mavlink  # noqa: E402  (selects MAVLink 2 / ardupilotmega)
from service_rig import free_udp_port, stop_process  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
AHRSD = Path(sys.executable).with_name("ahrsd")   # the console script installed beside the interpreter
OUR_COMP = 200
# `ahrsd run --sim` for a test whose guard is not the chip's rate (outputs, commands, GNSS, watchdog): the chip at
# a quarter of its 819.2 SPS ([sensor] rate_hz, SMPL_PRD 7), a quarter of the reader's and estimator's samples
LOW_RATE = ("--rate-hz", "204.8")
GCS_SYS, GCS_COMP = 255, 190


class Daemon:
    """An `ahrsd run` subprocess plus a pymavlink ground station listening on its udpout port.

    mag_calibrated: start with the simulated chip's magnetometer calibration in the state directory
    (bench/sim_calibration.py); without it and without GNSS the heading is unknown and no VPE is sent."""

    def __init__(self, tmp: Path, *extra: str, env: dict | None = None, scenario: str = "static",
                 source: tuple[str, ...] | None = None, mag_calibrated: bool = False):
        self.port = free_udp_port()
        self.state_dir = tmp / "state"
        if mag_calibrated:
            from bench.sim_calibration import save_mag_calibration, sim_chip_mag_model

            save_mag_calibration(self.state_dir, sim_chip_mag_model())
        self.log_path = tmp / "ahrsd.log"
        self.gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{self.port}", source_system=GCS_SYS,
                                              source_component=GCS_COMP, dialect="ardupilotmega")
        cmd = [str(AHRSD), "run", *(source or ("--sim", scenario)), "--mavlink",
               f"udpout:127.0.0.1:{self.port}", "--state-dir", str(self.state_dir), "--status-line", "off", *extra]
        full_env = dict(os.environ, PYTHONUNBUFFERED="1")
        full_env.update(env or {})
        self.log = open(self.log_path, "w")
        self.proc = subprocess.Popen(cmd, stdout=self.log, stderr=subprocess.STDOUT, env=full_env, cwd=REPO)
        self.sysid = 1

    def output(self) -> str:
        self.log.flush()
        return self.log_path.read_text()

    def recv(self, types=None, timeout: float = 5.0, cond=None):
        """Next message from our component matching types/cond (None on timeout)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            m = self.gcs.recv_match(type=types, blocking=True, timeout=0.2)
            if m is None:
                if self.proc.poll() is not None:
                    raise AssertionError(f"ahrsd exited with {self.proc.returncode}:\n{self.output()}")
                continue
            if m.get_srcComponent() != OUR_COMP:
                continue
            if cond is None or cond(m):
                return m
        return None

    def wait_active(self, timeout: float = 300.0) -> None:   # a loaded machine starts it in minutes
        hb = self.recv("HEARTBEAT", timeout, lambda m: m.system_status == mavlink.MAV_STATE_ACTIVE)
        assert hb is not None, f"no ACTIVE heartbeat:\n{self.output()}"
        self.sysid = hb.get_srcSystem()

    def collect(self, seconds: float) -> dict[str, list[tuple[float, object]]]:
        out: dict[str, list] = {}
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            m = self.gcs.recv_match(blocking=True, timeout=0.1)
            if m is not None and m.get_srcComponent() == OUR_COMP:
                out.setdefault(m.get_type(), []).append((time.monotonic(), m))
        return out

    def command(self, command: int, *params: float, target_component: int = OUR_COMP, confirmation: int = 0):
        p = list(params) + [0.0] * (7 - len(params))
        self.gcs.mav.command_long_send(self.sysid, target_component, command, confirmation, *p)

    def ack(self, command: int, timeout: float = 6.0):
        return self.recv("COMMAND_ACK", timeout, lambda m: m.command == command)

    def stop(self, timeout: float = 10.0) -> int:
        stop_process(self.proc, timeout)
        self.gcs.close()
        self.log.close()
        return self.proc.returncode
