"""Function calls the daemon's event loop makes, counted in the running daemon: `ahrsd run --sim boat --gnss-sim`
(the reader process, as bench/latency.py runs it) with cProfile switched on in the event loop's thread for a
window once ins is aided. Calls are a count, the same at any load and on any machine for the same work (the
loop's CPU follows the load; this does not), so two versions of the code compare in one run each:

    .venv/bin/python bench/loop_calls.py [--seconds 20] [--profile gcs|autopilot] [--top 40] [--by tottime|calls]

Printed: the window's loop calls a second (Python functions and C built-ins apart), per block handed over
(`SampleReader.process` calls), per sample and per message sent (`Endpoint.send` calls), and the functions with
the most calls (or own time, cProfile's, inflated by the profiler itself: a ranking only). The blocks a second
follow the load a little (a loaded machine merges hand-overs): compare per-block and per-sample figures.

Launched as `loop_calls.py --daemon OUT.prof -- run ...` it is the daemon itself: SIGUSR1 switches the profile
on, the next SIGUSR1 off and writes OUT.prof (pstats).
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ["MAVLINK20"] = "1"
os.environ["MAVLINK_DIALECT"] = "ardupilotmega"
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))
from bench.sim_calibration import save_mag_calibration, sim_chip_mag_model  # noqa: E402


def daemon_main(out: Path, argv: list[str]) -> int:
    """The daemon, with SIGUSR1 toggling cProfile in the thread that handles signals: the event loop's."""
    profiler = cProfile.Profile()
    state = {"on": False, "samples": 0}
    from ahrsd.daemon.pipeline import Pipeline

    pipelines = []                           # the daemon's pipelines: their sample counts over the window
    init = Pipeline.__init__

    def counted_init(self, *args, **kwargs) -> None:
        init(self, *args, **kwargs)
        pipelines.append(self)
    Pipeline.__init__ = counted_init

    def toggle(signum, frame) -> None:
        samples = sum(p.counters.samples for p in pipelines)
        if not state["on"]:
            state["samples"] = samples
            profiler.enable()
            state["on"] = True
            return
        profiler.disable()
        state["on"] = False
        Path(str(out) + ".samples").write_text(str(samples - state["samples"]))
        profiler.dump_stats(str(out))

    signal.signal(signal.SIGUSR1, toggle)
    from ahrsd.cli.main import main as cli_main

    return cli_main(argv)


def calls_of(stats: pstats.Stats, file_suffix: str, name: str) -> int:
    """Calls of the function `name` defined in a file whose path ends with `file_suffix`."""
    return sum(v[1] for k, v in stats.stats.items() if k[0].endswith(file_suffix) and k[2] == name)


def run(seconds: float, profile: str) -> tuple[pstats.Stats, float, int]:
    """(the window's stats, its wall seconds, the samples the pipeline took in it)."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
    sock.settimeout(0.5)
    with tempfile.TemporaryDirectory() as tmp:
        config = Path(tmp) / "ahrsd.toml"
        config.write_text(f'[sensor]\nreader = "process"\n\n[[endpoint]]\nurl = "udpout:127.0.0.1:'
                          f'{sock.getsockname()[1]}"\nprofile = "{profile}"\n')
        save_mag_calibration(tmp, sim_chip_mag_model("boat"))
        out = Path(tmp) / "loop.prof"
        proc = subprocess.Popen([sys.executable, __file__, "--daemon", str(out), "--", "run", "--sim", "boat",
                                 "--gnss-sim", "--config", str(config), "--state-dir", tmp, "--status-line", "off",
                                 "--no-log"], cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        try:
            deadline = time.monotonic() + 180.0
            aided = False
            while not aided and time.monotonic() < deadline:
                try:
                    data = sock.recv(65535)
                except socket.timeout:
                    continue
                aided = any(m.get_type() == "STATUSTEXT" and m.text.endswith(", aided")
                            for m in parser.parse_buffer(data) or ())
            if not aided:
                raise SystemExit("the daemon was never aided")
            time.sleep(3.0)                                   # the first fixes' one-off work
            t0 = time.monotonic()
            proc.send_signal(signal.SIGUSR1)
            end = t0 + seconds
            while time.monotonic() < end:                     # keep the socket drained
                try:
                    sock.recv(65535)
                except socket.timeout:
                    pass
            proc.send_signal(signal.SIGUSR1)
            wall = time.monotonic() - t0
            for _ in range(50):
                if out.exists() and out.stat().st_size:
                    break
                time.sleep(0.1)
            time.sleep(0.3)
            stats = pstats.Stats(str(out))
            samples = int(Path(str(out) + ".samples").read_text())
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(10)
            sock.close()
    return stats, wall, samples


def main() -> int:
    if len(sys.argv) > 2 and sys.argv[1] == "--daemon":
        return daemon_main(Path(sys.argv[2]), sys.argv[sys.argv.index("--") + 1:])
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--profile", choices=("gcs", "autopilot"), default="gcs")
    ap.add_argument("--top", type=int, default=40)
    ap.add_argument("--by", choices=("calls", "tottime"), default="calls")
    ap.add_argument("--save", type=Path, default=None, help="also write the window's pstats file here")
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f}, {time.strftime('%H:%M:%S', time.gmtime())} UTC")
    stats, wall, samples = run(args.seconds, args.profile)
    if args.save is not None:
        stats.dump_stats(str(args.save))
    total = sum(v[1] for v in stats.stats.values())
    builtin = sum(v[1] for k, v in stats.stats.items() if k[0] == "~")
    blocks = calls_of(stats, "sample_reader.py", "process")
    # samples: the pipeline's own count over the window (its generator is resumed once a run, not a sample, where
    # the reader takes whole runs)
    sent = calls_of(stats, "mavlink_io.py", "send")
    print(f"profile {args.profile}, {wall:.1f} s: {blocks / wall:.1f} blocks/s, {samples / wall:.1f} samples/s, "
          f"{sent / wall:.1f} messages sent/s")
    print(f"loop calls {total / wall:.0f}/s (Python {(total - builtin) / wall:.0f}, C {builtin / wall:.0f}); "
          f"a block {total / max(1, blocks):.0f} (Python {(total - builtin) / max(1, blocks):.0f})")
    rows = sorted(stats.stats.items(), key=lambda kv: -(kv[1][1] if args.by == "calls" else kv[1][2]))
    print(f"{'calls/s':>9s} {'/block':>7s} {'own µs':>7s}  function")
    for k, (cc, nc, tt, ct, callers) in rows[:args.top]:
        print(f"{nc / wall:9.1f} {nc / max(1, blocks):7.2f} {tt / max(1, nc) * 1e6:7.1f}  "
              f"{pstats.func_std_string(k).replace(str(REPO) + '/', '')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
