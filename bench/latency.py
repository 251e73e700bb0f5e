"""Sample-ready → MAVLink datagram latency and the daemon's CPU share at 819.2 SPS, with the default ("gcs")
outputs and with the autopilot profile (VISION_POSITION_ESTIMATE, SYS_STATUS, HEARTBEAT), without and with
GNSS, side by side.

Part A — `ahrsd run` as a subprocess on the simulated chip (real-time clock), MAVLink to a UDP socket here.
  Latency = arrival time of each VISION_POSITION_ESTIMATE / HIGHRES_IMU datagram (CLOCK_MONOTONIC, taken
  right after recv) − the sample time stamp it carries (`usec`/`time_usec`: the daemon's estimate of the
  moment the sample became ready, in CLOCK_MONOTONIC µs). CPU share = (utime + stime) / wall time of the daemon
  process over the window, from /proc/<pid>/stat.
Part B — the daemon's reader in-process for a few seconds: how far those time stamps are from the moment the
  simulated chip really produced each sample (its public `now()`/`sample_index`), so part A's figures can be
  read as true sample-ready latencies (true latency = A − B).

    .venv/bin/python bench/latency.py [--seconds 20] [--profile gcs|autopilot|both] [--log off|on|both]
                                      [--gnss off|on|both] [--scenario boat]

--gnss on: `--gnss-sim`, the scenario's simulated receiver (UBX NAV-PVT at 5 Hz over a pty, read by the serial
source as on hardware), so the default estimator is `ins` fed 5 fixes a second; off: no GNSS, `mekf`. Both run
the same moving scenario (`--scenario`, default boat), so the difference is the GNSS path and ins. The daemon's
figure includes the simulated receiver's writer thread (the simulator and the UBX encoding run in the daemon
process, as the simulated chip does); part C measures that thread's own cost in-process, to subtract. With
GNSS the window opens `--warmup` s after the first "aided" STATUSTEXT (ACTIVE alone without): the steady cost.

--log on: the daemon keeps its on-vehicle logs (raw samples .csv.gz + MAVLink .tlog, `--log-dir`); the disk
rate is the growth of the log directory over the window (the writer flushes every second).

Targets (docs/daemon.md, docs/gnss.md): p99 ≤ 2 ms, CPU ≤ 10 % of one core; with GNSS ≤ 12 %.
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ["MAVLINK20"] = "1"
os.environ["MAVLINK_DIALECT"] = "ardupilotmega"
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def free_udp_socket() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
    return s


def cpu_seconds(pid: int, tid: int | None = None) -> float:
    """utime + stime of the process, or of one of its threads (`tid`; the main thread's is the pid)."""
    path = f"/proc/{pid}/task/{tid}/stat" if tid is not None else f"/proc/{pid}/stat"
    fields = Path(path).read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")   # utime + stime


def dir_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in path.glob("*") if p.is_file()) if path.is_dir() else 0


def part_a(seconds: float, warmup: float, profile: str = "gcs", log: bool = False, gnss: bool = False,
           scenario: str = "static") -> dict:
    sock = free_udp_socket()
    port = sock.getsockname()[1]
    with tempfile.TemporaryDirectory() as tmp:
        config = Path(tmp) / "ahrsd.toml"
        config.write_text(f'[[endpoint]]\nurl = "udpout:127.0.0.1:{port}"\nprofile = "{profile}"\n')
        stats_path = Path(tmp) / "stats.json"
        proc = subprocess.Popen(
            [sys.executable, "-m", "ahrsd.cli", "run", "--sim", scenario, *(("--gnss-sim",) if gnss else ()),
             "--config", str(config),
             "--state-dir", tmp, "--status-line", "off", "--stats-file", str(stats_path),
             *(("--log-dir", str(Path(tmp) / "logs")) if log else ("--no-log",))],
            cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        sock.settimeout(0.5)
        lat: dict[str, list[float]] = {"VISION_POSITION_ESTIMATE": [], "HIGHRES_IMU": []}
        counts: dict[str, int] = {}
        t_start = None
        nbytes = 0
        cpu0 = 0.0
        try:
            deadline = time.monotonic() + 60.0
            active = aided = False
            while time.monotonic() < deadline:
                try:
                    data = sock.recv(4096)
                except socket.timeout:
                    continue
                now = time.monotonic()
                for m in parser.parse_buffer(data) or ():
                    mtype = m.get_type()
                    if mtype == "HEARTBEAT" and m.system_status == mavlink.MAV_STATE_ACTIVE:
                        active = True
                    if mtype == "STATUSTEXT" and m.text.endswith(", aided"):
                        aided = True
                    # with GNSS the window opens once ins is aided: the first fixes' one-off work (navigation
                    # set-up, the declination at the GNSS position) is start-up, not the steady cost
                    if t_start is None and active and (aided or not gnss):
                        deadline = now + warmup + seconds
                        t_start = now + warmup
                    if t_start is None or now < t_start:
                        continue
                    if cpu0 == 0.0:
                        cpu0, wall0 = cpu_seconds(proc.pid), time.monotonic()
                        main0 = cpu_seconds(proc.pid, proc.pid)
                        log0 = dir_bytes(Path(tmp) / "logs")
                    counts[mtype] = counts.get(mtype, 0) + 1
                    if mtype != "VISION_POSITION_ESTIMATE":
                        nbytes += len(m.get_msgbuf())
                    if mtype == "VISION_POSITION_ESTIMATE":
                        lat[mtype].append(now - m.usec * 1e-6)
                        nbytes += len(m.get_msgbuf())
                    elif mtype == "HIGHRES_IMU":
                        lat[mtype].append(now - m.time_usec * 1e-6)
            cpu1, wall1 = cpu_seconds(proc.pid), time.monotonic()
            main1 = cpu_seconds(proc.pid, proc.pid)
            log1 = dir_bytes(Path(tmp) / "logs")
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(10)
            sock.close()
        stats = json.loads(stats_path.read_text()) if stats_path.exists() else {}
    if not active or cpu0 == 0.0:
        raise SystemExit("the daemon never became ACTIVE")
    return {"latency_s": lat, "cpu_share": (cpu1 - cpu0) / (wall1 - wall0), "window_s": wall1 - wall0,
            "main_thread_share": (main1 - main0) / (wall1 - wall0),
            "counts": counts, "bytes_per_s": nbytes / (wall1 - wall0),
            "log_mb_per_h": (log1 - log0) / (wall1 - wall0) * 3600 / 1e6, "stats": stats}


def part_b(seconds: float) -> np.ndarray:
    """Time-stamp error t_s − true ready time of every sample the reader processes."""
    from ahrsd.daemon.config import Config, EndpointConfig, StateConfig
    from ahrsd.drivers.source import open_source
    from ahrsd.daemon.service import Service

    sink = free_udp_socket()
    with tempfile.TemporaryDirectory() as tmp:
        cfg = dataclasses.replace(Config(), endpoints=(EndpointConfig(f"udpout:127.0.0.1:{sink.getsockname()[1]}"),),
                                  state=StateConfig(tmp))
        source = open_source(cfg.sensor)
        bus = source.bus
        errors: list[float] = []
        read_one = source.read_one

        def timed_read(now: float):
            s = read_one(now)
            if s is not None:
                origin = time.monotonic() - bus.now()            # host time of chip time 0
                true_ready = origin + bus.sample_index / bus.sample_rate_hz
                errors.append(s.t_s - true_ready)
            return s

        source.read_one = timed_read
        service = Service(cfg, source=source)

        async def main():
            task = asyncio.create_task(service.run())
            await asyncio.sleep(seconds)
            service.request_stop()
            await task

        asyncio.run(main())
    sink.close()
    return np.array(errors[int(0.2 * len(errors)):])   # skip the lock-in


def part_c(scenario: str, seconds: float = 60.0) -> float:
    """CPU seconds per second of the simulated receiver's writer (drivers.gnss.scenario: the simulator's epochs
    and the UBX encoding into the pty), stepped in-process over `seconds` of scenario time."""
    import select

    from ahrsd.drivers.gnss.scenario import ScenarioGnssReceiver

    clock = type("Clock", (), {"t": 0.0, "__call__": lambda self: self.t})()
    rx = ScenarioGnssReceiver(scenario, clock)
    cpu = 0.0
    try:
        for k in range(int(seconds * 100)):
            clock.t = k / 100.0
            c0 = time.thread_time()
            rx.write_due()
            cpu += time.thread_time() - c0
            while select.select([rx.receiver.slave_fd], [], [], 0)[0]:
                os.read(rx.receiver.slave_fd, 4096)
    finally:
        rx.close()
    if rx.fixes_written < 0.9 * 5 * seconds:
        raise SystemExit(f"the simulated receiver wrote only {rx.fixes_written} fixes")
    return cpu / seconds


def gnss_summary(stats: dict) -> str:
    g = stats.get("gnss") or {}
    if not g:
        return "no GNSS"
    est = g.get("estimator")
    if est is None:
        return f"GNSS not fused; fixes accepted {g.get('accepted', 0)}"
    return (f"ins; fixes accepted {g.get('accepted', 0)}, fused velocity "
            f"{est.get('fused_velocity', 0)}, position {est.get('fused_position', 0)}, rejected {g.get('rejected', 0)}")


def pct(x: np.ndarray) -> str:
    p50, p99 = np.percentile(x, [50, 99])
    return f"p50 {p50 * 1e3:6.3f} ms  p99 {p99 * 1e3:6.3f} ms  max {x.max() * 1e3:6.3f} ms  (n={len(x)})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="measurement window of part A")
    ap.add_argument("--warmup", type=float, default=3.0)
    ap.add_argument("--profile", choices=("gcs", "autopilot", "both"), default="both",
                    help="the endpoint's output profile (both: one run each, side by side)")
    ap.add_argument("--log", choices=("off", "on", "both"), default="off",
                    help="on-vehicle logging in the daemon (both: one run each, side by side)")
    ap.add_argument("--gnss", choices=("off", "on", "both"), default="both",
                    help="--gnss-sim (ins with 5 Hz fixes) or no GNSS (mekf) (both: one run each, side by side)")
    ap.add_argument("--scenario", default=None,
                    help="the simulated scenario (default: boat, a moving one for GNSS; static with --gnss off)")
    args = ap.parse_args()
    scenario = args.scenario or ("static" if args.gnss == "off" else "boat")
    print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f} (shared machine)")
    profiles = ("gcs", "autopilot") if args.profile == "both" else (args.profile,)
    logs = {"off": (False,), "on": (True,), "both": (False, True)}[args.log]
    gnss_runs = {"off": (False,), "on": (True,), "both": (False, True)}[args.gnss]
    runs = {(p, lg, gn): part_a(args.seconds, args.warmup, p, lg, gn, scenario)
            for gn in gnss_runs for p in profiles for lg in logs}
    for (p, lg, gn), r in runs.items():
        print(f"\nA. ahrsd run --sim {scenario}{' --gnss-sim' if gn else ''}, profile \"{p}\", logging "
              f"{'on' if lg else 'off'}, {r['window_s']:.1f} s window")
        print(f"   {gnss_summary(r['stats'])}")
        for name, values in r["latency_s"].items():
            if values:
                print(f"   {name:25s} sample time stamp → datagram received: {pct(np.array(values))}")
        rates = ", ".join(f"{k} {v / r['window_s']:.1f}/s" for k, v in sorted(r["counts"].items()))
        print(f"   received: {rates}; {r['bytes_per_s']:.0f} B/s on the wire")
        print(f"   daemon CPU: {100 * r['cpu_share']:.1f} % of one core (utime+stime / wall), of which the event loop's "
              f"thread {100 * r['main_thread_share']:.1f} %")
        if lg:
            print(f"   log directory growth: {r['log_mb_per_h']:.1f} MB/h")
    rx_share = part_c(scenario) if True in gnss_runs else 0.0
    if len(runs) >= 2:
        print(f"\n   scenario {scenario}; load average {os.getloadavg()[0]:.2f}")
        print("   GNSS  profile    log   CPU % of one core (event loop thread)   B/s   log MB/h")
        for (p, lg, gn), r in runs.items():
            print(f"   {'on' if gn else 'off':4s}  {p:9s}  {'on' if lg else 'off':4s} {100 * r['cpu_share']:17.1f} "
                  f"({100 * r['main_thread_share']:4.1f})             {r['bytes_per_s']:5.0f}   {r['log_mb_per_h']:8.1f}")
    if rx_share:
        print(f"\nC. the simulated receiver's writer thread (in the daemon process with --gnss-sim; not there with a "
              f"real receiver): {100 * rx_share:.2f} % of one core")
    a = next(iter(runs.values()))
    b = part_b(5.0)
    print("\nB. time stamp − true chip sample-ready time (in-process reader, 5 s):")
    print(f"   {pct(b)}   min {b.min() * 1e3:.3f} ms")
    off = np.mean(b > 0.5 / 819.2)
    print(f"   {100 * off:.2f} % of samples stamped one period late (a wake later than a period: index ambiguity)")
    all_lat = np.concatenate([np.array(v) for v in a["latency_s"].values() if v])
    p99_true = np.percentile(all_lat, 99) + np.percentile(b, 99)
    print(f"\nTrue sample-ready → datagram p99 ≤ {p99_true * 1e3:.3f} ms (A p99 + B p99; target ≤ 2 ms); "
          f"CPU {100 * a['cpu_share']:.1f} % (target ≤ 10 %)")
    for (p, lg, gn), r in runs.items():
        if gn:
            print(f"With GNSS ({p}, logging {'on' if lg else 'off'}): CPU {100 * r['cpu_share']:.1f} % of one core "
                  f"(target ≤ 12 %), of which the simulated receiver about {100 * rx_share:.1f} %")


if __name__ == "__main__":
    main()
