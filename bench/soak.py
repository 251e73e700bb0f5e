"""Soak: `ahrsd run` on the simulated ADIS16405 (819.2 SPS) under a MAVLink flood and scheduled sensor faults.

    python bench/soak.py                 # 10 minutes (the issue's benchmark)
    python bench/soak.py --seconds 30    # a short run (tests/test_reliability_soak.py runs a shorter one)

A client floods the daemon with mixed traffic (valid requests that must be answered, junk bytes, truncated and
oversized frames, bad CRCs, hostile field values, unknown commands, refused parameter writes) while the
simulated chip injects faults on a schedule (--faults, `ahrsd run --sim-faults` syntax). At the end it prints
samples processed and lost (each lost sample explained: in a fault window, right after a reconnect, or a
reader overrun the daemon counted; "unexplained" = samples the chip produced that the daemon neither processed
nor counted; "over-counted" = lost samples counted that the chip did not lose, bounded by the reads whose index
was ambiguous), output messages received per type vs the configured rate (over the seconds no fault touched),
the latency sample → VISION_POSITION_ESTIMATE on the wire, the daemon's RSS at start and end, and every
counter. `--log on` runs the daemon with its on-vehicle logs (raw samples + .tlog, `--log-dir`; `--log-dir DIR`
puts them in DIR, e.g. a small tmpfs, to see a full disk): it then prints what each log wrote and dropped,
the disk rate, and the daemon's CPU share (printed in every run) to compare with a run without.
Exit status 1 if a criterion fails:

* zero unexplained lost samples, and no more over-counted ones than the daemon reported as ambiguous;
* each output within 5 % of its configured rate under the flood (fault-free seconds);
* RSS growth < 5 MB (from 10 s after start to the end);
* no exception escaped a task or a handler (exit code 0, no traceback in the log, handler_errors 0);
* ≥ 95 % of the valid requests answered (TIMESYNC: up to the per-sender limit, the rest counted refused);
* with logging on: every sample the daemon processed is written or counted as dropped by the sample log, and
  none is dropped while the log is healthy (a log stopped by a full disk says why and drops the rest).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import random
import signal
import socket
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter, defaultdict
from pathlib import Path

os.environ["MAVLINK20"] = "1"
os.environ["MAVLINK_DIALECT"] = "ardupilotmega"
from ahrsd.core import udp_drops  # noqa: E402
from ahrsd.daemon.mavlink_io import mavlink  # noqa: E402  (MAVLink 2, ardupilotmega)
from ahrsd.daemon.timesync_answers import ANSWERS_PER_S, BURST  # noqa: E402

if str(Path(__file__).resolve().parents[1]) not in sys.path:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.sim_calibration import save_mag_calibration, sim_chip_mag_model  # noqa: E402

OUR_COMP = 200
CONFIGURED_HZ = {"ATTITUDE": 50.0, "ATTITUDE_QUATERNION": 10.0, "VISION_POSITION_ESTIMATE": 30.0,
                 "HIGHRES_IMU": 10.0, "SYS_STATUS": 1.0, "HEARTBEAT": 1.0}   # docs/daemon.md defaults
RATE_TOLERANCE = 0.05
RSS_GROWTH_LIMIT_MB = 5.0
ANSWER_RATIO_MIN = 0.95
WARMUP_S = 10.0
# one fault of each kind that stops the flow, plus the ones that only flag samples, repeating
DEFAULT_FAULTS = ("bus_error@20-21:every=60;stall@35-35.5:every=60;garbage@45-50:p=0.02,every=60;"
                  "alarm@10-10.5:bits=SUPPLY_LOW,every=60;stuck_axis@50-53:axis=mag_x,every=60;"
                  "burst_bug@30-35:every=60;short_read@25-27:p=0.01,every=60;saturation@55-55.2:axis=accel_x,every=60")
CI_FAULTS = ("alarm@3-3.5:bits=SUPPLY_LOW;garbage@4-6:p=0.02;bus_error@7-8;stall@11-11.5;"
             "stuck_axis@13-15:axis=mag_x;short_read@16-17:p=0.01;burst_bug@18-20")


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


class Flood:
    """Mixed valid/invalid traffic at `rate` datagrams per second to the daemon's address."""

    def __init__(self, sock: socket.socket, addr, sysid: int, rate: float, seed: int):
        self.sock, self.addr, self.rate = sock, addr, rate
        self.rng = random.Random(seed)
        self.mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        self.sysid = sysid
        self.sent = Counter()
        self.valid_sent = Counter()          # requests that must be answered, by answer kind
        self.timesync_marks: set[int] = set()
        self.stop = threading.Event()

    def pack(self, msg) -> bytes:
        return bytes(msg.pack(self.mav))

    def one(self) -> tuple[str, bytes]:
        r, rng, mav = self.rng.random(), self.rng, self.mav
        if r < 0.15:
            idx = rng.randrange(11)                          # the 11 parameters (docs/daemon.md)
            self.valid_sent["param_value"] += 1
            return "param_read", self.pack(mav.param_request_read_encode(self.sysid, OUR_COMP, b"", idx))
        if r < 0.25:
            mark = rng.getrandbits(48) | 1
            self.timesync_marks.add(mark)
            self.valid_sent["timesync"] += 1
            return "timesync", self.pack(mav.timesync_encode(0, mark))
        if r < 0.35:
            self.valid_sent["ack"] += 1
            return "get_interval", self.pack(mav.command_long_encode(
                self.sysid, OUR_COMP, mavlink.MAV_CMD_GET_MESSAGE_INTERVAL, 0, 30, 0, 0, 0, 0, 0, 0))
        if r < 0.42:
            return "heartbeat", self.pack(mav.heartbeat_encode(6, 8, 0, 0, 4))
        if r < 0.52:
            return "junk", bytes(rng.getrandbits(8) for _ in range(rng.randrange(1, 280)))
        if r < 0.60:
            frame = self.pack(mav.param_request_read_encode(self.sysid, OUR_COMP, b"SR_ATTITUDE", -1))
            return "truncated", frame[:rng.randrange(1, len(frame) - 1)]
        if r < 0.68:
            frame = bytearray(self.pack(mav.command_long_encode(self.sysid, OUR_COMP, 510, 0, 30, 0, 0, 0, 0, 0, 0)))
            frame[rng.randrange(10, len(frame))] ^= 1 << rng.randrange(8)
            return "bad_crc", bytes(frame)
        if r < 0.73:
            frame = bytearray(self.pack(mav.timesync_encode(0, 7)))
            frame[1] = 255                                         # oversized: length says 255 bytes
            return "oversized", bytes(frame) + bytes(rng.getrandbits(8) for _ in range(40))
        if r < 0.80:
            value = rng.choice([math.nan, math.inf, -math.inf, 1e30, -1e30])
            self.valid_sent["param_value"] += 1                   # refused, but answered with the value in force
            name = rng.choice([b"SR_ATTITUDE", b"MNT_ROLL_DEG", b"DECL_DEG"])
            return "hostile_param_set", self.pack(mav.param_set_encode(self.sysid, OUR_COMP, name, value, 9))
        if r < 0.86:
            self.valid_sent["ack"] += 1                             # SET_MESSAGE_INTERVAL with junk: DENIED
            return "hostile_command", self.pack(mav.command_long_encode(
                self.sysid, OUR_COMP, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                rng.choice([math.nan, 1e9, -7.0]), rng.choice([math.nan, math.inf, -5.0]), 0, 0, 0, 0, 0))
        if r < 0.92:
            self.valid_sent["ack"] += 1                             # unknown command: UNSUPPORTED
            return "unknown_command", self.pack(mav.command_long_encode(
                self.sysid, OUR_COMP, rng.randrange(40000, 65535), 0, *[rng.uniform(-1e6, 1e6)] * 7))
        if r < 0.96:
            return "unknown_param_id", self.pack(mav.param_request_read_encode(
                self.sysid, OUR_COMP, b"Z" * 16, -1))              # 16 chars, no terminator, not ours
        return "param_list", self.pack(mav.param_request_list_encode(self.sysid, OUR_COMP))

    def run(self) -> None:
        period = 1.0 / self.rate
        nxt = time.monotonic()
        while not self.stop.is_set():
            kind, data = self.one()
            try:
                self.sock.sendto(data, self.addr)
                self.sent[kind] += 1
            except OSError:
                self.sent["send_error"] += 1
            nxt += period
            delay = nxt - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            elif delay < -1.0:
                nxt = time.monotonic()


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")   # utime + stime


def dir_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in path.glob("*") if p.is_file()) if path.is_dir() else 0


def soak(seconds: float, faults: str, flood_rate: float, seed: int, workdir: Path, verbose: bool,
         log_dir: Path | None = None) -> dict:
    """log_dir: the daemon logs raw samples and MAVLink traffic there (None: --no-log)."""
    port_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    port_sock.bind(("127.0.0.1", 0))
    port_sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
    port = port_sock.getsockname()[1]
    stats_path = workdir / "stats.json"
    log_path = workdir / "ahrsd.log"
    save_mag_calibration(workdir / "state", sim_chip_mag_model())    # without it no heading, no VPE, is sent
    cmd = [sys.executable, "-m", "ahrsd.cli", "run", "--sim", "static", "--mavlink",
           f"udpout:127.0.0.1:{port}", "--state-dir", str(workdir / "state"), "--status-line", "off",
           "--stats-file", str(stats_path)]
    cmd += ["--log-dir", str(log_dir)] if log_dir is not None else ["--no-log"]
    if faults:
        cmd += ["--sim-faults", faults]
    log = open(log_path, "w")
    proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=dict(os.environ, PYTHONUNBUFFERED="1"))
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    port_sock.settimeout(0.2)
    arrivals: dict[str, list[float]] = defaultdict(list)
    states: list[tuple[float, int]] = []
    texts: list[tuple[float, str]] = []
    latencies: list[float] = []
    answers = Counter()
    last_sys_status = None
    daemon_addr = None
    flood = None
    rss_start = rss_end = None
    client_drops = 0
    rss_trace: list[tuple[float, float]] = []
    t_start = None
    cpu = {}
    try:
        deadline_boot = time.monotonic() + 180
        while True:                                              # wait for the first ACTIVE heartbeat
            if proc.poll() is not None or time.monotonic() > deadline_boot:
                raise RuntimeError(f"daemon did not become ACTIVE:\n{log_path.read_text()[-3000:]}")
            try:
                data, addr = port_sock.recvfrom(65536)
            except socket.timeout:
                continue
            msgs = parser.parse_buffer(data) or ()
            if any(m.get_type() == "HEARTBEAT" and m.system_status == mavlink.MAV_STATE_ACTIVE for m in msgs):
                daemon_addr, sysid = addr, msgs[0].get_srcSystem()
                break
        t_start = time.monotonic()
        cpu["start"] = (cpu_seconds(proc.pid), t_start, dir_bytes(log_dir) if log_dir else 0)
        flood = Flood(port_sock, daemon_addr, sysid, flood_rate, seed)
        threading.Thread(target=flood.run, daemon=True).start()
        t_end = t_start + seconds
        next_rss = t_start + WARMUP_S
        while time.monotonic() < t_end:
            if proc.poll() is not None:
                raise RuntimeError(f"daemon exited with {proc.returncode}:\n{log_path.read_text()[-3000:]}")
            now = time.monotonic()
            if now >= next_rss:
                r = rss_mb(proc.pid)
                rss_trace.append((now - t_start, r))
                rss_start = r if rss_start is None else rss_start
                next_rss = now + 10.0
            try:
                data = port_sock.recv(65536)
            except socket.timeout:
                continue
            recv_t = time.monotonic()
            for m in parser.parse_buffer(data) or ():
                if m.get_srcComponent() != OUR_COMP:
                    continue
                mtype = m.get_type()
                arrivals[mtype].append(recv_t)
                if mtype == "HEARTBEAT":
                    states.append((recv_t, m.system_status))
                elif mtype == "VISION_POSITION_ESTIMATE":
                    latencies.append(recv_t - m.usec * 1e-6)
                elif mtype == "STATUSTEXT":
                    texts.append((recv_t, m.text))
                elif mtype == "SYS_STATUS":
                    last_sys_status = m
                elif mtype == "PARAM_VALUE":
                    answers["param_value"] += 1
                elif mtype == "COMMAND_ACK":
                    answers["ack"] += 1
                elif mtype == "TIMESYNC" and m.ts1 in flood.timesync_marks:
                    answers["timesync"] += 1
        flood.stop.set()
        drain_end = time.monotonic() + 1.0                       # answers in flight
        while time.monotonic() < drain_end:
            try:
                data = port_sock.recv(65536)
            except (socket.timeout, BlockingIOError):
                break
            for m in parser.parse_buffer(data) or ():
                t = m.get_type()
                if t == "PARAM_VALUE":
                    answers["param_value"] += 1
                elif t == "COMMAND_ACK":
                    answers["ack"] += 1
                elif t == "TIMESYNC" and m.ts1 in flood.timesync_marks:
                    answers["timesync"] += 1
        client_drops = udp_drops.socket_drops(port_sock.fileno())   # answers this machine dropped on their way in
        rss_end = rss_mb(proc.pid)
        cpu["end"] = (cpu_seconds(proc.pid), time.monotonic(), dir_bytes(log_dir) if log_dir else 0)
        rss_trace.append((time.monotonic() - t_start, rss_end))
    finally:
        if flood is not None:
            flood.stop.set()
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        log.close()
        port_sock.close()
    stats = json.loads(stats_path.read_text()) if stats_path.exists() else {}
    return dict(seconds=seconds, t_start=t_start, t_end=t_start + seconds, arrivals=arrivals, states=states,
                texts=texts, latencies=latencies, answers=answers, flood=flood, rss_start=rss_start,
                rss_end=rss_end, rss_trace=rss_trace, stats=stats, client_drops=client_drops, exit_code=proc.returncode,
                log=log_path.read_text(), last_sys_status=last_sys_status, cpu=cpu, logging=log_dir is not None)


def fault_free_seconds(r: dict) -> list[int]:
    """Whole seconds of the run (after the first) during which the daemon said ACTIVE before, during and after
    (heartbeats within ±1.5 s all ACTIVE) and no sensor STATUSTEXT arrived."""
    t0 = r["t_start"]
    bad = set()
    for t, s in r["states"]:
        if s != mavlink.MAV_STATE_ACTIVE:
            for k in range(int(t - t0) - 2, int(t - t0) + 3):
                bad.add(k)
    for t, text in r["texts"]:
        if "sensor" in text or "CRITICAL" in text or "STANDBY" in text:
            for k in range(int(t - t0) - 2, int(t - t0) + 3):
                bad.add(k)
    return [k for k in range(1, int(r["seconds"]) - 1) if k not in bad]


def answers_accounted(valid_sent: dict, answers: dict, timesync_refused: int, daemon_drops: int,
                      client_drops: int, seconds: float) -> tuple[list[str], list[str]]:
    """(report lines, failed criteria) of the flood's valid requests: each kind answered on ≥ ANSWER_RATIO_MIN of
    them (TIMESYNC: up to the per-sender limit, the rest counted refused). A request the daemon never read because
    the kernel dropped it (its socket's buffer full while the daemon stalled on a loaded machine), or an answer
    dropped on its way into this client, is counted by the kernel (core.udp_drops), not lost unseen: a kind fails
    only when its unanswered requests are more than the kernel counted dropped."""
    lines, failed = [], []
    kernel_drops = daemon_drops + client_drops
    lines.append(f"  datagrams the kernel dropped: {daemon_drops} on the daemon's socket, {client_drops} on the client's")
    for kind, n in sorted(valid_sent.items()):
        got = answers.get(kind, 0)
        # a PARAM_REQUEST_LIST also answers with 16 PARAM_VALUEs: count at most one per request sent
        if kind == "param_value":
            got = min(got, n)
        refused = ""
        if kind == "timesync":
            # the flood is one sender: its requests are answered up to its limit (daemon/timesync_answers.py), and
            # every one beyond is counted refused
            counted = got + timesync_refused
            refused = f"; {timesync_refused} counted refused beyond {ANSWERS_PER_S:g}/s"
            if counted < ANSWER_RATIO_MIN * n and n - counted > kernel_drops:
                failed.append(f"only {counted} of {n} timesync requests answered or counted refused")
            n = min(n, int(BURST + ANSWERS_PER_S * seconds))
        ratio = min(got / n, 1.0) if n else 1.0
        lines.append(f"  answers {kind:12s} {got:7d} of {n:7d} ({ratio:.1%}){refused}")
        if ratio < ANSWER_RATIO_MIN and n - got > kernel_drops:
            failed.append(f"only {ratio:.1%} of the {kind} requests answered ({n - got} unanswered, "
                          f"{kernel_drops} counted dropped by the kernel)")
    return lines, failed


def evaluate(r: dict) -> tuple[list[str], list[str]]:
    """(report lines, failed criteria)."""
    lines, failed = [], []
    st = r["stats"]
    pipe, src, svc = st.get("pipeline", {}), st.get("source", {}), st.get("service", {})
    chip_total = src.get("chip_last_index_read", -1) - src.get("chip_first_index_read", 0) + 1
    # + the indices the reader thread had read but not handed over when the daemon stopped (the chip counts them)
    daemon_total = (pipe.get("samples", 0) + pipe.get("lost_samples", 0)
                    + src.get("reader_undelivered_at_close", 0))
    unexplained = max(0, chip_total - daemon_total)
    lines.append(f"samples processed           {pipe.get('samples', 0):>10d}   "
                 f"({pipe.get('samples', 0) / max(1, chip_total):.1%} of the {chip_total} the chip produced while read)")
    lines.append(f"samples lost (counted)      {pipe.get('lost_samples', 0):>10d}   in {pipe.get('gaps', 0)} gaps")
    lines.append(f"  in fault windows          {src.get('sensor_lost_in_fault_windows', 0):>10d}")
    lines.append(f"  right after a reconnect   {src.get('sensor_lost_after_reconnect', 0):>10d}")
    lines.append(f"  reader overruns (CPU)     {src.get('sensor_lost_outside_faults', 0):>10d}   "
                 f"({svc.get('overruns', 0)} late wakes counted)")
    over = max(0, daemon_total - chip_total)
    ambiguous = src.get("index_ambiguous_samples", 0)
    lines.append(f"chip samples in read range  {chip_total:>10d}   processed + counted lost = {daemon_total}")
    lines.append(f"unexplained lost samples    {unexplained:>10d}   (reads whose index differed from the chip's: "
                 f"{src.get('sensor_index_mismatches', 0)})")
    # without a sample counter a read that straddles a ready time has two possible indices; the daemon takes
    # the larger (a loss is never hidden) and counts how many of its lost samples may be phantoms
    lines.append(f"over-counted (phantom) lost {over:>10d}   (at most {ambiguous} possible, from "
                 f"{src.get('index_ambiguous_reads', 0)} ambiguous reads)")
    if unexplained:
        failed.append(f"{unexplained} lost samples not counted by the daemon")
    if over > ambiguous:
        failed.append(f"{over} lost samples counted that the chip did not lose, beyond the {ambiguous} ambiguous")

    ok_secs = fault_free_seconds(r)
    lines.append(f"outputs (fault-free seconds: {len(ok_secs)} of {int(r['seconds'])})")
    lines.append(f"  {'message':26s} {'received':>9s} {'rate Hz':>8s} {'configured':>10s} {'ratio':>6s}")
    t0 = r["t_start"]
    for name, hz in CONFIGURED_HZ.items():
        times = r["arrivals"].get(name, [])
        n_all = len(times)
        ok = set(ok_secs)
        # Rate from the intervals between consecutive arrivals that both fall in fault-free seconds: counting
        # messages per second bin would be off by one whenever a 1 Hz message sits at a bin edge.
        gaps = [b - a for a, b in zip(times, times[1:]) if int(a - t0) in ok and int(b - t0) in ok]
        rate = len(gaps) / sum(gaps) if gaps else float("nan")
        ratio = rate / hz
        lines.append(f"  {name:26s} {n_all:9d} {rate:8.2f} {hz:10.1f} {ratio:6.3f}")
        # one message of arrival jitter over the measured span (matters for 1 Hz in a short run)
        tolerance = RATE_TOLERANCE + 1.0 / (max(1, len(gaps)) + 1)
        if not (abs(ratio - 1.0) <= tolerance):
            failed.append(f"{name} at {rate:.2f} Hz, configured {hz:g} Hz (±{RATE_TOLERANCE:.0%})")
    lat = sorted(r["latencies"])
    if lat:
        p = lambda q: lat[min(len(lat) - 1, int(q * len(lat)))] * 1e3   # noqa: E731
        lines.append(f"latency sample → VPE on the wire: p50 {p(0.5):.2f} ms  p99 {p(0.99):.2f} ms  "
                     f"max {lat[-1] * 1e3:.2f} ms  ({len(lat)} messages)")
    growth = (r["rss_end"] or 0) - (r["rss_start"] or 0)
    lines.append(f"daemon RSS: {r['rss_start']:.1f} MB at {WARMUP_S:.0f} s, {r['rss_end']:.1f} MB at the end "
                 f"(growth {growth:+.2f} MB; trace {' '.join(f'{v:.1f}' for _, v in r['rss_trace'][:: max(1, len(r['rss_trace']) // 12)])})")
    if not growth < RSS_GROWTH_LIMIT_MB:
        failed.append(f"RSS grew {growth:.2f} MB")
    fl = r["flood"]
    lines.append(f"flood sent: {sum(fl.sent.values())} datagrams ({sum(fl.sent.values()) / r['seconds']:.0f}/s): "
                 + ", ".join(f"{k} {v}" for k, v in sorted(fl.sent.items())))
    daemon_drops = sum(c.get("rx_dropped_by_kernel", 0) for c in st.get("links", {}).values())
    answer_lines, answer_failed = answers_accounted(fl.valid_sent, r["answers"], svc.get("timesync_refused", 0),
                                                    daemon_drops, r.get("client_drops", 0), r["seconds"])
    lines += answer_lines
    failed += answer_failed
    links = st.get("links", {})
    for url, c in links.items():
        lines.append(f"link {url}: " + ", ".join(f"{k} {len(v) if k in ('skips', 'held_runs') else v}" for k, v in c.items()))
    ss = r["last_sys_status"]
    if ss is not None:
        lines.append(f"last SYS_STATUS: errors_comm {ss.errors_comm}, count1 (refused unsigned) {ss.errors_count1}, "
                     f"count2 (missed samples) {ss.errors_count2}, count3 (late samples) {ss.errors_count3}, "
                     f"count4 (sensor errors) {ss.errors_count4}")
    if "start" in r["cpu"] and "end" in r["cpu"]:
        (c0, w0, b0), (c1, w1, b1) = r["cpu"]["start"], r["cpu"]["end"]
        lines.append(f"daemon CPU {100 * (c1 - c0) / (w1 - w0):.1f} % of one core over the soak (utime+stime / wall, "
                     f"flood included; load average {os.getloadavg()[0]:.2f})"
                     + (f"; log directory growth {(b1 - b0) / (w1 - w0) * 3600 / 1e6:.1f} MB/h" if r["logging"] else ""))
    if r["logging"]:
        logs = st.get("logs", {})
        for name in ("samples", "tlog"):
            c = logs.get(name)
            if c is None:
                failed.append(f"logging was on but the stats have no {name} log")
                continue
            lines.append(f"log {name}: written {c['written']}, dropped {c['dropped']}, files {c['files_opened']} "
                         f"(deleted {c['files_deleted']}), failure {c['failure']}, writer thread CPU "
                         f"{c.get('writer_cpu_s', 0.0):.2f} s over the run (≈ {100 * c.get('writer_cpu_s', 0.0) / r['seconds']:.2f} % "
                         "of one core over the soak window)")
            if c["failure"] is None and c["dropped"]:
                failed.append(f"the {name} log dropped {c['dropped']} entries while healthy")
        c = logs.get("samples")
        if c is not None and c["written"] + c["dropped"] != pipe.get("samples", 0):
            failed.append(f"the sample log accounts for {c['written'] + c['dropped']} samples, the daemon processed "
                          f"{pipe.get('samples', 0)}")
    lines.append("commands: " + ", ".join(f"{k} {v}" for k, v in st.get("commands", {}).items())
                 + f"; params rejected_writes {st.get('params', {}).get('rejected_writes', 0)}")
    lines.append("faults injected (chip): " + ", ".join(f"{k} {v}" for k, v in sorted(st.get("faults_injected", {}).items())))
    counted = {k: v for k, v in sorted(src.items()) if v and not k.startswith("chip_")
               and k not in ("samples", "new_samples")}
    lines.append("driver/source counters: " + ", ".join(f"{k} {v}" for k, v in counted.items()))
    lines.append("service counters: " + ", ".join(f"{k} {v}" for k, v in svc.items()))
    lines.append(f"STATUSTEXTs: {len(r['texts'])}; states seen: "
                 + ", ".join(f"{k} {v}" for k, v in Counter(s for _, s in r["states"]).items()))
    tracebacks = r["log"].count("Traceback")
    log_lines = r["log"].splitlines()
    task_failed = sum(1 for x in log_lines if " task " in x and "failed" in x)
    handler_errors = st.get("commands", {}).get("handler_errors", 0) + sum(
        1 for x in log_lines if "handling " in x and "failed" in x)
    lines.append(f"daemon exit code {r['exit_code']}, tracebacks in log {tracebacks}, handler errors {handler_errors}")
    if r["exit_code"] != 0 or tracebacks or handler_errors or st.get("exit_code", 0) != 0 or task_failed:
        failed.append("an exception escaped (exit code, traceback, handler error or failed task)")
    return lines, failed


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seconds", type=float, default=600.0, help="soak duration after the daemon is ACTIVE (600)")
    p.add_argument("--faults", default=None, help="--sim-faults schedule (default: a repeating mix; '' = none)")
    p.add_argument("--flood-rate", type=float, default=300.0, help="client datagrams per second (300)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--keep", metavar="DIR", help="keep the daemon's log and stats in DIR")
    p.add_argument("--log", choices=("off", "on"), default="off",
                   help="the daemon's on-vehicle logs (raw samples + .tlog) off or on (default off)")
    p.add_argument("--log-dir", metavar="DIR", help="log into DIR (implies --log on; default: the work directory)")
    args = p.parse_args(argv)
    faults = args.faults if args.faults is not None else (DEFAULT_FAULTS if args.seconds > 120 else CI_FAULTS)
    with tempfile.TemporaryDirectory(prefix="ahrsd-soak-") as tmp:
        workdir = Path(args.keep) if args.keep else Path(tmp)
        workdir.mkdir(parents=True, exist_ok=True)
        log_dir = Path(args.log_dir) if args.log_dir else workdir / "logs" if args.log == "on" else None
        print(f"soak: {args.seconds:.0f} s, flood {args.flood_rate:.0f}/s, faults: {faults or 'none'}, logging "
              f"{'off' if log_dir is None else f'on into {log_dir}'}", flush=True)
        r = soak(args.seconds, faults, args.flood_rate, args.seed, workdir, False, log_dir)
        lines, failed = evaluate(r)
    print("\n".join(lines))
    if failed:
        print("FAILED: " + "; ".join(failed))
        return 1
    print("PASS: zero unexplained lost samples, output rates within 5 %, RSS growth < 5 MB, no escaped exception")
    return 0


if __name__ == "__main__":
    sys.exit(main())
