"""What an `ahrsd run` start costs, per process: the CPU (user + system, /proc/PID/stat) of the daemon, its sensor
reader (multiprocessing's spawn), multiprocessing's resource tracker and the simulated chip's block producer
(drivers.sim_block_producer) at the daemon's first ATTITUDE, and the last seen of each before the daemon has
exited after a SIGTERM there. The daemon runs as the tests run it (tests/support/ahrsd_process.py: `--sim static
--rate-hz 204.8`, a udpout port with a pymavlink ground station on it), with bytecode writing on as in the suite.

    python bench/start_cpu.py [--runs N] [--rate-hz HZ] [--run-s S]
    python bench/start_cpu.py --imports

One JSON line per run. `--run-s S`: the daemon runs S seconds more after its first ATTITUDE, and each process's
CPU-s a second over them is added (`running_cpu_s_per_s`). `--imports`: no daemon; the CPU-s (process_time) of
each step of a daemon's start in this interpreter, in the daemon's order (the third-party packages first, then
ours, then the estimator's kernels loaded by a make_estimator), one JSON line. Compare two trees by running it in each, alternated, with the load of the moment (the
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


def one_run(state_dir: Path, rate_hz: str = "204.8", run_s: float = 0.0) -> dict:
    from pymavlink import mavutil      # here, not at the top: --imports times its import as a daemon's step

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", dialect="ardupilotmega")
    cmd = [str(AHRSD), "run", "--sim", "static", "--rate-hz", rate_hz, "--mavlink", f"udpout:127.0.0.1:{port}",
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
        running = {}
        if run_s > 0:
            end = time.monotonic() + run_s
            while time.monotonic() < end:
                gcs.recv_match(blocking=True, timeout=0.1)
            later = _tree_cpu_s(proc.pid, roles)
            running = {k: round((v - first.get(k, 0.0)) / run_s, 4) for k, v in later.items()}
        proc.send_signal(signal.SIGTERM)
        last = dict(first)
        while proc.poll() is None:
            last.update(_tree_cpu_s(proc.pid, roles))
            time.sleep(0.01)
    gcs.close()
    out = {"first_attitude_wall_s": round(wall_s, 2), "at_first_attitude_cpu_s": first,
           "last_seen_cpu_s": last, "exit_code": proc.returncode, "load_1min": round(os.getloadavg()[0], 1)}
    if running:
        out["running_cpu_s_per_s"] = running
    return out


# pymavlink through ahrsd.daemon.mavlink_io, as the daemon imports it (that module keeps mavutil's MAVLink 1 dialect out)
IMPORT_STEPS = ("numpy", "numba", "scipy.linalg", "ahrsd.daemon.mavlink_io", "ahrsd.cli.main", "ahrsd.estimator",
                "ahrsd.cli.run", "ahrsd.daemon.config", "ahrsd.drivers.source", "ahrsd.daemon.service")


def import_steps() -> dict:
    """process_time of each step of a daemon's start, in this interpreter: numba's registries import scipy.linalg
    when the first kernel loads (numba.np.arraymath `_check_blas`), so it is a step of its own here."""
    import importlib

    steps, before = {}, time.process_time()
    for name in IMPORT_STEPS:
        importlib.import_module(name)
        now = time.process_time()
        steps[name], before = round(now - before, 3), now
    from ahrsd.estimator import make_estimator

    make_estimator("mekf")
    steps["make_estimator (kernels loaded)"] = round(time.process_time() - before, 3)
    return {"steps_cpu_s": steps, "total_cpu_s": round(time.process_time(), 3),
            "load_1min": round(os.getloadavg()[0], 1)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--rate-hz", default="204.8", help="the simulated chip's rate (ahrsd run --rate-hz)")
    ap.add_argument("--run-s", type=float, default=0.0, help="seconds the daemon runs on after its first ATTITUDE")
    ap.add_argument("--imports", action="store_true", help="the start's steps in this interpreter, no daemon")
    args = ap.parse_args()
    if args.imports:
        print(json.dumps(import_steps()), flush=True)
        return 0
    for _ in range(args.runs):
        with tempfile.TemporaryDirectory() as tmp:
            print(json.dumps(one_run(Path(tmp) / "state", args.rate_hz, args.run_s)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
