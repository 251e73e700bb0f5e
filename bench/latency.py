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
                                      [--gnss off|on|both] [--scenario boat] [--sensor sim,sim-process,iio|all]
                                      [--load off|on|both]

--sensor: `sim-process` is the simulated spidev path as the daemon runs it by default (the byte-level chip read
by a reader process, drivers.process_source, the real chip's path; its CPU is added to the daemon's); `sim` the
same chip read by a reader thread in the daemon's process (`[sensor] reader = "thread"`, for comparison); `iio`
the simulated IIO path (drivers.simulated_iio: a sysfs tree and a FIFO fed by a simulated kernel in a process
of its own, started by this bench, so the daemon's figure holds only what it costs with the real kernel driver:
draining the buffer and decoding records). The simulated chip's samples are computed in a producer process
(drivers.sim_block_producer: the chip's silicon), reported apart, not in the daemon's CPU.
--load on: while measuring, one busy process per CPU (`while True: pass`, at this bench's nice level) and a
MAVLink flood into the daemon's endpoint (HEARTBEAT, ATTITUDE and TIMESYNC requests at --flood-hz).
Every run reports the samples the chip produced and the daemon missed (`--stats-file` `samples`: missed, late,
corrupt; whole run, start-up included) beside the ground truth (simulated chip's own loss accounting, or the
simulated kernel's records) and the load average. Targets (issue 31): 0 missed in 10 min idle, ≤ 0.1 % under
load, for the simulated spidev path and the simulated IIO path:

    nice -n 10 .venv/bin/python bench/latency.py --gnss off --profile autopilot --sensor sim-process,iio \
        --load both --seconds 600 --skip-b

--gnss on: `--gnss-sim`, the scenario's simulated receiver (UBX NAV-PVT at 5 Hz over a pty, read by the serial
source as on hardware), so the default estimator is `ins` fed 5 fixes a second; off: no GNSS, `mekf`. Both run
the same moving scenario (`--scenario`, default boat), so the difference is the GNSS path and ins. With `--sensor iio`
(`--gnss-sim` follows only the daemon's own simulated chip) the scenario's receiver runs on the simulated IIO chip's
time in a process of its own (bench/iio_gnss.py) and the daemon reads its pty as `[gnss] source = "serial"`; its CPU
and the simulated kernel's are printed beside the daemon's, not in it. On the sim paths the daemon's
figure includes the simulated receiver's writer thread (the simulator and the UBX encoding run in the daemon
process, as the simulated chip does), measured apart (below). With
GNSS the window opens `--warmup` s after the first "aided" STATUSTEXT (ACTIVE alone without): the steady cost.

--threads: each thread of the daemon's processes over the window, user and system CPU and wakes (voluntary context
switches) a second, from /proc: the event loop, the reader process's reading thread, the simulated receiver's writer.
--split: the daemon is started through bench/loop_split.py, which times every event-loop callback and named parts
(taking the blocks, the per-sample path, the outputs, a GNSS fix, each housekeeping job) with the thread's CPU clock;
the split over the window is printed (calls a second, µs a call, % of a core). Its clock reads cost a little CPU
of their own: compare --split runs with --split runs.

--log on: the daemon keeps its on-vehicle logs (raw samples .csv.gz + MAVLink .tlog, `--log-dir`); the disk
rate is the growth of the log directory over the window (the writer flushes every second).

Targets (docs/daemon.md "Performance", issue 28): p99 ≤ 2 ms, CPU ≤ 10 % of one core, with GNSS too (docs/gnss.md
kept an older ≤ 12 % with GNSS). The CPU figure is the daemon's processes (event loop and reader process), so it
holds the simulated parts that run inside them: the simulated chip's register model (the SPI bus) in the reader
and, with --gnss-sim, the simulated receiver's writer thread; the 9.9 % of docs/daemon.md was measured that way.
The run measures them itself: the reading thread's CPU time inside the simulated chip's transfers and its ground
truth's bookkeeping (drivers.ground_truth), the receiver's writer thread's CPU time (drivers.gnss.scenario), each
over the time it ran (`--stats-file`); every run prints them and the daemon's own figure without them beside
the total ("own": what the issue's ≤ 10 % is judged on; the total stays printed).
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import json
import os
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

os.environ["MAVLINK20"] = "1"
os.environ["MAVLINK_DIALECT"] = "ardupilotmega"
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))
from bench.sim_calibration import save_mag_calibration, sim_chip_mag_model  # noqa: E402


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


def tree_cpu_seconds(pid: int) -> tuple[float, float, float]:
    """utime + stime of the process and its descendants (the sensor reader process of `sim-process`): (the
    daemon's, its reader process's alone — part of the daemon's —, the simulated chip's block producer's —
    drivers.sim_block_producer, the chip's silicon, which a real chip does not take from the host)."""
    daemon = reader = producer = 0.0
    todo = [pid]
    while todo:
        p = todo.pop()
        try:
            cpu = cpu_seconds(p)
            cmdline = Path(f"/proc/{p}/cmdline").read_bytes()
        except (OSError, ValueError):
            continue
        if b"sim_block_producer" in cmdline:
            producer += cpu
        else:
            daemon += cpu
            if b"multiprocessing" in cmdline:        # the spawned reader process (drivers.process_source)
                reader += cpu
        for task in Path(f"/proc/{p}/task").glob("*"):
            try:
                todo += [int(c) for c in (task / "children").read_text().split()]
            except (OSError, ValueError):
                continue
    return daemon, reader, producer


def outside_cpu_seconds(device, receiver) -> tuple[float, float]:
    """utime + stime of the simulated hardware the bench runs beside the daemon with --sensor iio: (the simulated
    kernel's process — drivers.simulated_iio, the kernel's work on hardware —, the GNSS receiver's process —
    bench/iio_gnss.py, a receiver's own work —); 0 for what is not running."""
    def of(pid) -> float:
        try:
            return cpu_seconds(pid) if pid else 0.0
        except (OSError, ValueError):
            return 0.0

    return (of(device.kernel_pid) if device is not None else 0.0,
            of(receiver.pid) if receiver is not None else 0.0)


def thread_counts(pid: int) -> dict[tuple[str, int], tuple[float, float, int, int]]:
    """Per thread of the daemon's processes (the simulated chip's block producer left out): (which process —
    "daemon" or "reader" —, tid) → (utime s, stime s, voluntary context switches, involuntary ones), from
    /proc/<pid>/task/<tid>/stat and status. A thread's voluntary switches are its waits: a wake each."""
    out: dict[tuple[str, int], tuple[float, float, int, int]] = {}
    tick = os.sysconf("SC_CLK_TCK")
    todo = [pid]
    while todo:
        p = todo.pop()
        try:
            cmdline = Path(f"/proc/{p}/cmdline").read_bytes()
        except OSError:
            continue
        who = "reader" if b"multiprocessing" in cmdline else "daemon"
        for task in Path(f"/proc/{p}/task").glob("*"):
            try:
                todo += [int(c) for c in (task / "children").read_text().split()]
                if b"sim_block_producer" in cmdline:
                    continue
                fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
                status = dict(line.split(":", 1) for line in (task / "status").read_text().splitlines())
                out[(who, int(task.name))] = (int(fields[11]) / tick, int(fields[12]) / tick,
                                              int(status["voluntary_ctxt_switches"]),
                                              int(status["nonvoluntary_ctxt_switches"]))
            except (OSError, ValueError, KeyError):
                continue
    return out


def threads_table(pid: int, t0: dict, t1: dict, wall_s: float) -> list[str]:
    """Lines: each thread's user and system CPU (% of a core) and wakes a second over the window, busiest first;
    the main thread of the daemon's process is its event loop."""
    rows = []
    for key, (u1, s1, v1, n1) in t1.items():
        u0, s0, v0, n0 = t0.get(key, (0.0, 0.0, 0, 0))
        who, tid = key
        name = "event loop" if who == "daemon" and tid == pid else ("main" if tid == pid else "thread")
        rows.append((u1 - u0 + s1 - s0, f"   {who:6s} {tid:8d} {name:10s} user {100 * (u1 - u0) / wall_s:5.2f} %  "
                     f"system {100 * (s1 - s0) / wall_s:5.2f} %  wakes {(v1 - v0) / wall_s:7.1f}/s  "
                     f"preempted {(n1 - n0) / wall_s:6.1f}/s"))
    return [line for _, line in sorted(rows, key=lambda r: -r[0])]


def split_table(line0: dict, line1: dict) -> list[str]:
    """Lines: bench/loop_split.py's split of the event loop's CPU between two of its snapshots."""
    from bench.loop_split import split

    wall, loop_pct, rows = split(line0, line1)
    lines = [f"   event loop, timed in it (bench/loop_split.py, {wall:.1f} s): thread CPU {loop_pct:.2f} % of a core"]
    lines += [f"     {name[:58]:58s} {rate:7.1f}/s {us:8.1f} µs {pc:6.2f} %" + (f"  ({items:.1f} items/s)" if items else "")
              for name, rate, us, pc, items in rows]
    return lines


SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)     # Linux include/uapi/asm-generic/socket.h (= SCM_)


def kernel_receipt(ancillary, now: float) -> float:
    """The kernel's receipt time of a datagram (SCM_TIMESTAMPNS, CLOCK_REALTIME) on CLOCK_MONOTONIC (`now` when the
    kernel gave none)."""
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS:
            sec, nsec = struct.unpack("qq", data[:16])
            return sec + nsec * 1e-9 - (time.time() - time.monotonic())
    return now


def dir_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in path.glob("*") if p.is_file()) if path.is_dir() else 0


class Load:
    """One busy process per CPU and a MAVLink flood into the daemon's endpoint (from the bench's socket)."""

    def __init__(self, sock: socket.socket, flood_hz: float):
        self.busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(os.cpu_count() or 1)]
        self.sock, self.flood_hz, self.peer = sock, flood_hz, None
        self.sent = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._flood, daemon=True)
        self._thread.start()

    def _flood(self) -> None:
        mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        msgs = [lambda: mav.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4),
                lambda: mav.attitude_encode(int(time.monotonic() * 1e3) & 0xFFFFFFFF, 0.01, 0.02, 0.5, 0, 0, 0),
                lambda: mav.timesync_encode(0, time.monotonic_ns())]
        period, t = 1.0 / self.flood_hz, time.monotonic()
        while not self._stop.is_set():
            if self.peer is not None:
                for i in range(10):
                    try:
                        self.sock.sendto(msgs[self.sent % 3]().pack(mav), self.peer)
                        self.sent += 1
                    except OSError:
                        pass
            t += 10 * period
            time.sleep(max(0.0, t - time.monotonic()))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        for p in self.busy:
            p.kill()
            p.wait()


def part_a(seconds: float, warmup: float, profile: str = "gcs", log: bool = False, gnss: bool = False,
           scenario: str = "static", sensor: str = "sim", load: bool = False, flood_hz: float = 1000.0,
           floor: bool = False, rate_hz: float | None = None, threads: bool = False,
           split: bool = False, trace: bool = False) -> dict:
    sock = free_udp_socket()
    port = sock.getsockname()[1]
    with tempfile.TemporaryDirectory() as tmp:
        config = Path(tmp) / "ahrsd.toml"
        reader = {"sim": "thread", "sim-process": "process"}.get(sensor, "auto")   # iio: auto, a thread
        rate = f"rate_hz = {rate_hz}\n" if rate_hz is not None else ""          # sim/spi: SMPL_PRD, iio: the driver's
        stats_path = Path(tmp) / "stats.json"
        device = receiver = None
        gnss_table = ""
        if sensor == "iio":
            from ahrsd.drivers.simulated_iio import SimulatedIioDevice

            device = SimulatedIioDevice(Path(tmp) / "iio", scenario=scenario)
            source_args = ["--iio", str(device.sysfs)]
            if gnss:            # the same vehicle's receiver on the chip's time, read as a UART (bench/iio_gnss.py)
                from bench.iio_gnss import IioGnssReceiver

                device.wait_ready()
                receiver = IioGnssReceiver(device, scenario)
                gnss_table = (f'[gnss]\nsource = "serial"\ndevice = "{receiver.device}"\nbaud = {receiver.baud}\n'
                              f'protocol = "ubx"\nlatency_s = {receiver.latency_s}\n\n')
        else:
            source_args = ["--sim", scenario]
        config.write_text(f'[sensor]\nreader = "{reader}"\n{rate}\n{gnss_table}'
                          f'[[endpoint]]\nurl = "udpout:127.0.0.1:{port}"\nprofile = "{profile}"\n')
        # the scenario's own iron (the boat's is not the static chip's): without a calibration (and GNSS) no
        # heading, no VPE, is sent, and with a wrong one the GNSS path would be measured rejecting it
        save_mag_calibration(tmp, sim_chip_mag_model(scenario))
        split_path = Path(tmp) / "split.jsonl"
        trace_path = Path(tmp) / "trace.json"
        launcher = ([str(REPO / "bench" / "loop_split.py"), str(split_path), "--"] if split else
                    [str(REPO / "bench" / "iio_trace.py"), str(trace_path), "--"] if trace else ["-m", "ahrsd.cli"])
        proc = subprocess.Popen(
            [sys.executable, *launcher, "run", *source_args, *(("--gnss-sim",) if gnss and device is None else ()),
             "--config", str(config),
             "--state-dir", tmp, "--status-line", "off", "--stats-file", str(stats_path),
             *(("--log-dir", str(Path(tmp) / "logs")) if log else ("--no-log",))],
            cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        sock.settimeout(0.5)
        # the kernel's receipt time of each datagram (SO_TIMESTAMPNS, CLOCK_REALTIME) as well as this process's:
        # the bench's own wake after a datagram arrived is not the daemon's latency
        sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        lat_kernel: list[float] = []
        lat: dict[str, list[float]] = {"VISION_POSITION_ESTIMATE": [], "HIGHRES_IMU": []}
        vpe: list[tuple[int, float]] = []       # (usec, arrival) of each VPE in the window (--trace)
        counts: dict[str, int] = {}
        t_start = None
        nbytes = 0
        cpu0 = 0.0
        loader = None
        floor_proc, floor_out = None, None
        try:
            # with GNSS and no magnetometer calibration the daemon is ACTIVE only once its heading is good
            # (the GNSS yaw aligned and converged: ~85 s on the simulated boat), not within 60 s
            deadline = time.monotonic() + (180.0 if gnss else 60.0)
            active = aided = False
            while time.monotonic() < deadline:
                try:
                    data, ancillary, _flags, addr = sock.recvmsg(65535, 64)
                except socket.timeout:
                    continue
                now = time.monotonic()
                stamp = kernel_receipt(ancillary, now)
                if load and loader is None and t_start is not None:
                    loader = Load(sock, flood_hz)
                if loader is not None:
                    loader.peer = addr
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
                        if floor:               # the bare real-time loop beside the daemon, for the window
                            floor_proc = subprocess.Popen(
                                [sys.executable, str(REPO / "bench" / "wake_floor.py"), "--seconds",
                                 str(deadline - now), "--json"], stdout=subprocess.PIPE, text=True)
                        (cpu0, reader0, chip0), wall0 = tree_cpu_seconds(proc.pid), time.monotonic()
                        outside0 = outside_cpu_seconds(device, receiver)
                        main0 = cpu_seconds(proc.pid, proc.pid)
                        threads0 = thread_counts(proc.pid) if threads else {}
                        if split:
                            proc.send_signal(signal.SIGUSR1)
                        log0 = dir_bytes(Path(tmp) / "logs")
                    counts[mtype] = counts.get(mtype, 0) + 1
                    if mtype != "VISION_POSITION_ESTIMATE":
                        nbytes += len(m.get_msgbuf())
                    if mtype == "VISION_POSITION_ESTIMATE":
                        lat[mtype].append(now - m.usec * 1e-6)
                        lat_kernel.append(stamp - m.usec * 1e-6)
                        vpe.append((m.usec, now))
                        nbytes += len(m.get_msgbuf())
                    elif mtype == "HIGHRES_IMU":
                        lat[mtype].append(now - m.time_usec * 1e-6)
            (cpu1, reader1, chip1), wall1 = tree_cpu_seconds(proc.pid), time.monotonic()
            outside1 = outside_cpu_seconds(device, receiver)
            main1 = cpu_seconds(proc.pid, proc.pid)
            threads1 = thread_counts(proc.pid) if threads else {}
            if split:
                proc.send_signal(signal.SIGUSR1)
                time.sleep(0.5)
                lines = [json.loads(x) for x in split_path.read_text().splitlines()]
            log1 = dir_bytes(Path(tmp) / "logs")
            if floor_proc is not None:
                floor_out = json.loads(floor_proc.communicate(timeout=60)[0])
        finally:
            if floor_proc is not None and floor_proc.poll() is None:
                floor_proc.kill()
            flooded = loader.sent if loader is not None else 0
            if loader is not None:
                loader.close()
            if device is not None:
                device.close()                 # the "kernel" stops first: the daemon drains what it wrote
                time.sleep(1.0)
            rx_counts = receiver.counters() if receiver is not None else {}
            if receiver is not None:
                receiver.close()
            proc.send_signal(signal.SIGTERM)
            proc.wait(10)
            sock.close()
            trace_lines = []
            if trace and trace_path.exists() and cpu0:
                from bench.iio_trace import stage_table

                trace_lines = stage_table(json.loads(trace_path.read_text()), vpe, wall0, wall1)
        stats = json.loads(stats_path.read_text()) if stats_path.exists() else {}
        truth = (device.lost_truth() if device is not None else
                 stats.get("source", {}).get("sensor_lost_outside_faults"))
    if not active or cpu0 == 0.0:
        raise SystemExit("the daemon never became ACTIVE")
    return {"latency_s": lat, "vpe_kernel_s": lat_kernel, "cpu_share": (cpu1 - cpu0) / (wall1 - wall0), "window_s": wall1 - wall0,
            "chip_share": (chip1 - chip0) / (wall1 - wall0), "load_avg": os.getloadavg(),
            "iio_kernel_share": (outside1[0] - outside0[0]) / (wall1 - wall0),
            "iio_receiver_share": (outside1[1] - outside0[1]) / (wall1 - wall0), "iio_receiver": rx_counts,
            "reader_share": (reader1 - reader0) / (wall1 - wall0), "floor": floor_out,
            "main_thread_share": (main1 - main0) / (wall1 - wall0),
            "counts": counts, "bytes_per_s": nbytes / (wall1 - wall0),
            "log_mb_per_h": (log1 - log0) / (wall1 - wall0) * 3600 / 1e6, "stats": stats,
            "lost_truth": truth, "flooded": flooded,
            "threads": threads_table(proc.pid, threads0, threads1, wall1 - wall0) if threads else [],
            "split": split_table(lines[0], lines[1]) if split else [], "trace": trace_lines}


def part_b(seconds: float) -> np.ndarray:
    """Time-stamp error t_s − true ready time of every sample the reader processes."""
    from ahrsd.daemon.config import Config, EndpointConfig, StateConfig
    from ahrsd.drivers.source import open_source
    from ahrsd.daemon.service import Service

    sink = free_udp_socket()
    with tempfile.TemporaryDirectory() as tmp:
        cfg = dataclasses.replace(Config(), endpoints=(EndpointConfig(f"udpout:127.0.0.1:{sink.getsockname()[1]}"),),
                                  state=StateConfig(tmp))
        source = open_source(dataclasses.replace(cfg.sensor, reader="thread"))   # the chip in this process
        bus = source.bus
        errors: list[float] = []
        chip_source = getattr(source, "inner", source)       # under drivers.threaded_source's reader thread
        read_one = chip_source.read_one

        def timed_read(now: float):
            s = read_one(now)
            if s is not None:
                origin = time.monotonic() - bus.now()            # host time of chip time 0
                true_ready = origin + bus.sample_index / bus.sample_rate_hz
                errors.append(s.t_s - true_ready)
            return s

        chip_source.read_one = timed_read
        service = Service(cfg, source=source)

        async def main():
            task = asyncio.create_task(service.run())
            await asyncio.sleep(seconds)
            service.request_stop()
            await task

        asyncio.run(main())
    sink.close()
    return np.array(errors[int(0.2 * len(errors)):])   # skip the lock-in


def simulated_in_daemon(stats: dict) -> tuple[float, float]:
    """Shares of a core that the simulated hardware running inside the daemon's processes took, as the run
    measured them (`--stats-file`): (the simulated chip — its register model, i.e. the SPI bus, and its ground
    truth's loss bookkeeping, thread CPU time accumulated around them in the reading thread since the first
    read, drivers.ground_truth —, the simulated receiver's writer thread — its own thread CPU time since it
    started, drivers.gnss.scenario —), each as CPU seconds over the seconds it was measured over. Both are 0
    where they are not in the daemon (a real chip, the IIO path's simulated kernel and the chip's block producer,
    which run in processes of their own, no GNSS)."""
    def rate(cpu_s, wall_s) -> float:
        return float(cpu_s) / float(wall_s) if wall_s else 0.0

    src = stats.get("source", {})
    rx = (stats.get("gnss") or {}).get("sim_receiver", {})
    return (rate(src.get("sensor_simulated_cpu_s", 0.0), src.get("sensor_simulated_wall_s", 0.0)),
            rate(rx.get("writer_cpu_s", 0.0), rx.get("writer_wall_s", 0.0)))


def gnss_summary(stats: dict) -> str:
    g = stats.get("gnss") or {}
    if not g:
        return "no GNSS"
    est = g.get("estimator")
    if est is None:
        return f"GNSS not fused; fixes accepted {g.get('accepted', 0)}"
    return (f"ins; fixes accepted {g.get('accepted', 0)}, fused velocity "
            f"{est.get('fused_velocity', 0)}, position {est.get('fused_position', 0)}, rejected {g.get('rejected', 0)}")


def samples_summary(r: dict) -> str:
    acc = r["stats"].get("samples", {})
    produced = acc.get("delivered", 0) + acc.get("missed", 0)
    return (f"{acc.get('delivered', 0)} delivered, missed {acc.get('missed', 0)} "
            f"({100 * acc.get('missed', 0) / max(1, produced):.3f} %), late {acc.get('late', 0)}, corrupt "
            f"{acc.get('corrupt', 0)} (whole run); ground truth of the samples lost: {r['lost_truth']}")


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
    ap.add_argument("--sensor", default="sim-process",
                    help="comma-separated: sim-process (simulated spidev chip read by a reader process: the "
                    "default reader, real or simulated), sim (the same chip read by a thread in the daemon), iio "
                    "(simulated IIO device; with GNSS its vehicle's receiver on a pty, bench/iio_gnss.py), or all")
    ap.add_argument("--load", choices=("off", "on", "both"), default="off",
                    help="busy processes on every CPU and a MAVLink flood while measuring (both: one run each)")
    ap.add_argument("--flood-hz", type=float, default=1000.0, help="MAVLink messages per second in the flood")
    ap.add_argument("--floor", action="store_true",
                    help="run bench/wake_floor.py's bare real-time loop beside each window: the periods it "
                    "misses per second are the machine's floor for any user-space reader, in the same run")
    ap.add_argument("--threads", action="store_true",
                    help="print each thread of the daemon's processes: user and system CPU, wakes (voluntary "
                    "context switches) and preemptions a second over the window")
    ap.add_argument("--split", action="store_true",
                    help="run the daemon through bench/loop_split.py and print where its event loop's CPU goes "
                    "(every loop callback and named parts timed with the thread's CPU clock over the window)")
    ap.add_argument("--trace", action="store_true",
                    help="--sensor iio: run the daemon through bench/iio_trace.py and print each VPE's latency split "
                    "into its stages (age of the sample at the read, decode, the loop's wake, the outputs, the bench)")
    ap.add_argument("--skip-b", action="store_true", help="skip part B (the in-process time-stamp check)")
    ap.add_argument("--rate-hz", type=float, default=None,
                    help="[sensor] rate_hz for part A (default: the chip's 819.2 SPS; with iio, written to the "
                    "kernel driver's sampling_frequency)")
    args = ap.parse_args()
    scenario = args.scenario or ("static" if args.gnss == "off" else "boat")
    print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f} (shared machine)")
    profiles = ("gcs", "autopilot") if args.profile == "both" else (args.profile,)
    logs = {"off": (False,), "on": (True,), "both": (False, True)}[args.log]
    gnss_runs = {"off": (False,), "on": (True,), "both": (False, True)}[args.gnss]
    sensors = ("sim", "sim-process", "iio") if args.sensor == "all" else tuple(args.sensor.split(","))
    loads = {"off": (False,), "on": (True,), "both": (False, True)}[args.load]
    full = {(p, lg, gn, se, ld): part_a(args.seconds, args.warmup, p, lg, gn, scenario, se, ld, args.flood_hz,
                                        args.floor, args.rate_hz, args.threads, args.split,
                                        args.trace and se == "iio")
            for se in sensors for ld in loads for gn in gnss_runs for p in profiles for lg in logs}
    runs = {k[:3]: r for k, r in full.items() if k[3] == sensors[0] and k[4] == loads[0]}
    for r in full.values():
        r["sim_chip_share"], r["sim_rx_share"] = simulated_in_daemon(r["stats"])
        r["sim_share"] = r["sim_chip_share"] + r["sim_rx_share"]
    for (p, lg, gn, se, ld), r in full.items():
        print(f"\nA. ahrsd run {'--iio (simulated IIO device)' if se == 'iio' else '--sim'} {scenario} ({se})"
              f"{(' --gnss-serial (its receiver: bench/iio_gnss.py)' if se == 'iio' else ' --gnss-sim') if gn else ''}, profile \"{p}\", logging {'on' if lg else 'off'}, "
              f"load {'on' if ld else 'off'}, {r['window_s']:.1f} s window"
              f"{f', [sensor] rate_hz = {args.rate_hz:g}' if args.rate_hz is not None else ''}")
        print(f"   {gnss_summary(r['stats'])}")
        for name, values in r["latency_s"].items():
            if values:
                print(f"   {name:25s} sample time stamp → datagram received: {pct(np.array(values))}")
                if name == "VISION_POSITION_ESTIMATE" and r["vpe_kernel_s"]:
                    print(f"   {name:25s} sample time stamp → kernel receipt:    {pct(np.array(r['vpe_kernel_s']))}")
        rates = ", ".join(f"{k} {v / r['window_s']:.1f}/s" for k, v in sorted(r["counts"].items()))
        print(f"   received: {rates}; {r['bytes_per_s']:.0f} B/s on the wire")
        print(f"   daemon CPU: {100 * r['cpu_share']:.1f} % of one core (utime+stime / wall), of which the event loop's "
              f"thread {100 * r['main_thread_share']:.1f} %; the simulated chip's block producer (not the daemon's) "
              f"{100 * r['chip_share']:.1f} %; the reader process alone {100 * r['reader_share']:.1f} %")
        print(f"   of the daemon's figure, simulated hardware inside its processes (not there on hardware; measured in "
              f"the run): {100 * r['sim_share']:.1f} % (the chip's register model and truth bookkeeping "
              f"{100 * r['sim_chip_share']:.1f} %, the receiver's writer {100 * r['sim_rx_share']:.1f} %); "
              f"the daemon's own code {100 * (r['cpu_share'] - r['sim_share']):.1f} %")
        if se == "iio":
            rx = r["iio_receiver"]
            print(f"   beside the daemon, not in its figure (simulated hardware in processes of their own): the "
                  f"simulated kernel (drivers.simulated_iio: the IIO driver's handler and the chip) "
                  f"{100 * r['iio_kernel_share']:.1f} %"
                  + (f"; the GNSS receiver (bench/iio_gnss.py) {100 * r['iio_receiver_share']:.1f} %, fixes written "
                     f"{rx.get('fixes_written', 0)}, skipped late {rx.get('fixes_skipped_late', 0)} (whole run)"
                     if gn else ""))
        if r["floor"]:
            fl = r["floor"]
            print(f"   floor beside it (bench/wake_floor.py, real-time {'yes' if fl['realtime'] else 'NO'}): "
                  f"{fl['late']} periods missed of {fl['wakes']} ({100 * fl['late'] / max(1, fl['wakes']):.3f} %), "
                  f"worst wake {fl['worst_s'] * 1e3:.1f} ms")
        for line in r["threads"] + r["split"] + r["trace"]:
            print(line)
        print(f"   load average at the end: {r['load_avg'][0]:.2f} (1 min), {r['load_avg'][1]:.2f} (5 min)")
        if lg:
            print(f"   log directory growth: {r['log_mb_per_h']:.1f} MB/h")
        print(f"   samples: {samples_summary(r)}")
        src = r["stats"].get("source", {})
        if "reader_wakes_late" in src:
            chip = "sensor_producer_wait_max_us" in src            # the simulated chip, with its block producer
            print(f"   reader: real-time priority {'yes' if src.get('reader_realtime_priority') else 'NO'}"
                  f"{(' (its producer ' + ('too)' if src.get('reader_helpers_realtime') else 'not)')) if chip else ''}, "
                  f"{src['reader_wakes_late']} wakes later than a period (worst "
                  f"{src.get('reader_wake_late_max_us', 0) / 1e3:.1f} ms), hand-over dropped "
                  f"{src.get('reader_handover_dropped', 0)}; reads that waited for the simulated chip's producer "
                  f"{src.get('sensor_producer_waits', 0)} (worst {src.get('sensor_producer_wait_max_us', 0) / 1e3:.1f} ms)")
        if ld:
            print(f"   load: {os.cpu_count()} busy processes, {r['flooded']} MAVLink messages flooded in; TIMESYNC "
                  f"answers received {r['counts'].get('TIMESYNC', 0) / r['window_s']:.1f}/s, requests not answered "
                  f"(the per-sender limit, daemon.timesync_answers) {r['stats'].get('service', {}).get('timesync_refused', 0)}"
                  f" (whole run)")
    if len(full) >= 2 or len(sensors) > 1 or len(loads) > 1:
        print(f"\n   per path, scenario {scenario}, {args.seconds:g} s windows; load average {os.getloadavg()[0]:.2f}")
        print("   CPU %: the daemon's processes (the issue's ≤ 10 % target: docs/daemon.md \"Performance\"); own: "
              "without the simulated chip's bus and receiver that run inside them (measured in the run)")
        print("   sensor       load  GNSS  profile    CPU % (loop thread) reader   own   delivered   missed   lost %  "
              "missed/s  floor/s   late  corrupt  truth  load avg")
        for (p, lg, gn, se, ld), r in full.items():
            acc = r["stats"].get("samples", {})
            produced = acc.get("delivered", 0) + acc.get("missed", 0)
            fl = r["floor"]
            floor_s = f"{fl['late'] / (fl['wakes'] / 819.2):8.2f}" if fl else "       -"
            print(f"   {se:11s}  {'on' if ld else 'off':4s}  {'on' if gn else 'off':4s}  {p:9s} "
                  f"{100 * r['cpu_share']:6.1f} ({100 * r['main_thread_share']:4.1f}) {100 * r['reader_share']:6.1f} "
                  f"{100 * (r['cpu_share'] - r['sim_share']):5.1f}   {acc.get('delivered', 0):8d}"
                  f"  {acc.get('missed', 0):7d}  {100 * acc.get('missed', 0) / max(1, produced):6.3f}  "
                  f"{acc.get('missed', 0) / max(1.0, produced / 819.2):8.2f} {floor_s}  "
                  f"{acc.get('late', 0):5d}  {acc.get('corrupt', 0):7d}  {r['lost_truth']!s:5s}  "
                  f"{r['load_avg'][0]:.2f}")
    if len(runs) >= 2:
        print(f"\n   scenario {scenario}; load average {os.getloadavg()[0]:.2f}")
        print("   GNSS  profile    log   CPU % of one core (event loop thread)   B/s   log MB/h")
        for (p, lg, gn), r in runs.items():
            print(f"   {'on' if gn else 'off':4s}  {p:9s}  {'on' if lg else 'off':4s} {100 * r['cpu_share']:17.1f} "
                  f"({100 * r['main_thread_share']:4.1f})             {r['bytes_per_s']:5.0f}   {r['log_mb_per_h']:8.1f}")
    a = next(iter(runs.values()))
    if args.skip_b:
        return
    b = part_b(5.0)
    print("\nB. time stamp − true chip sample-ready time (in-process reader, 5 s):")
    print(f"   {pct(b)}   min {b.min() * 1e3:.3f} ms")
    off = np.mean(b > 0.5 / 819.2)
    print(f"   {100 * off:.2f} % of samples stamped one period late (a wake later than a period: index ambiguity)")
    all_lat = np.concatenate([np.array(v) for v in a["latency_s"].values() if v])
    p99_true = np.percentile(all_lat, 99) + np.percentile(b, 99)
    print(f"\nTrue sample-ready → datagram p99 ≤ {p99_true * 1e3:.3f} ms (A p99 + B p99; target ≤ 2 ms); "
          f"CPU {100 * a['cpu_share']:.1f} % (target ≤ 10 %; own {100 * (a['cpu_share'] - a['sim_share']):.1f} %)")
    for (p, lg, gn), r in runs.items():
        if gn:
            print(f"With GNSS ({p}, logging {'on' if lg else 'off'}): CPU {100 * r['cpu_share']:.1f} % of one core "
                  f"(target ≤ 10 %), of which the simulated parts about {100 * r['sim_share']:.1f} %")


if __name__ == "__main__":
    main()
