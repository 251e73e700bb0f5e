"""What an `ahrsd run` start costs, per process: the CPU (user + system, /proc/PID/stat) of the daemon, its sensor
reader (multiprocessing's spawn), multiprocessing's resource tracker and the simulated chip's block producer
(drivers.sim_block_producer) at the daemon's first ATTITUDE, and the last seen of each before the daemon has
exited after a SIGTERM there. The daemon runs as the tests run it (tests/support/ahrsd_process.py: `--sim static
--rate-hz 204.8`, a udpout port with a pymavlink ground station on it), with bytecode writing on as in the suite.

    python bench/start_cpu.py [--runs N]

One JSON line per run. Compare two trees by running it in each, alternated, with the load of the moment (the
figures move with it); the first run after a change of the kernels' sources compiles them (tens of CPU-s)."""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.pop("PYTHONDONTWRITEBYTECODE", None)   # as tests/conftest.py: the suite's processes write bytecode
os.environ["MAVLINK20"] = "1"
os.environ["MAVLINK_DIALECT"] = "ardupilotmega"
from pymavlink import mavutil  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
AHRSD = Path(sys.executable).with_name("ahrsd")
TICKS_S = os.sysconf("SC_CLK_TCK")


def _stat(pid: int):
    """(parent pid, user + system CPU-s) of a process, None once it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2:].split()
    return int(fields[1]), (int(fields[11]) + int(fields[12])) / TICKS_S


def _role(pid: int, roles: dict) -> str:
    if pid not in roles:
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_text().replace("\0", " ")
        except OSError:
            cmd = ""
        roles[pid] = ("tracker" if "resource_tracker" in cmd else "reader" if "spawn_main" in cmd
                      else "producer" if "sim_block_producer" in cmd else "daemon" if " run " in cmd else str(pid))
    return roles[pid]


def _tree_cpu_s(root: int, roles: dict) -> dict[str, float]:
    """CPU-s of `root` and each of its descendants, by role."""
    procs = {}
    for d in os.listdir("/proc"):
        if d.isdigit() and (s := _stat(int(d))) is not None:
            procs[int(d)] = s
    tree, grown = {root}, True
    while grown:
        grown = False
        for pid, (ppid, _) in procs.items():
            if ppid in tree and pid not in tree:
                tree.add(pid)
                grown = True
    return {_role(p, roles): procs[p][1] for p in tree if p in procs}


def one_run(state_dir: Path) -> dict:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", dialect="ardupilotmega")
    cmd = [str(AHRSD), "run", "--sim", "static", "--rate-hz", "204.8", "--mavlink", f"udpout:127.0.0.1:{port}",
           "--state-dir", str(state_dir), "--status-line", "off"]
    roles: dict = {}
    t0 = time.monotonic()
    with open(state_dir.parent / "ahrsd.log", "w") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=REPO,
                                env=dict(os.environ, PYTHONUNBUFFERED="1"))
        while gcs.recv_match(type="ATTITUDE", blocking=True, timeout=0.05) is None:
            _tree_cpu_s(proc.pid, roles)     # learns each process's role while its command line is readable
            if proc.poll() is not None or time.monotonic() - t0 > 300:
                raise SystemExit(f"no ATTITUDE; the daemon's output is in {state_dir.parent / 'ahrsd.log'}")
        first = _tree_cpu_s(proc.pid, roles)
        wall_s = time.monotonic() - t0
        proc.send_signal(signal.SIGTERM)
        last = dict(first)
        while proc.poll() is None:
            last.update(_tree_cpu_s(proc.pid, roles))
            time.sleep(0.01)
    gcs.close()
    return {"first_attitude_wall_s": round(wall_s, 2), "at_first_attitude_cpu_s": first,
            "last_seen_cpu_s": last, "exit_code": proc.returncode, "load_1min": round(os.getloadavg()[0], 1)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1)
    args = ap.parse_args()
    for _ in range(args.runs):
        with tempfile.TemporaryDirectory() as tmp:
            print(json.dumps(one_run(Path(tmp) / "state")), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
