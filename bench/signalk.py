"""ahrsd's NMEA 0183 output read by a real Signal K server (docs/marine.md "Signal K").

    python bench/signalk.py [--seconds 30] [--scenario level-turns]

First use installs `signalk-server` (SIGNALK_SERVER_VERSION, from the npm registry) into
~/.cache/ahrsd/signalk-server with `npm ci` from bench/signalk_server's lockfile; needs Node.js ≥ 20. The server
runs on loopback ports with its own settings directory (a temporary folder: an NMEA 0183 UDP input, mDNS and the
NMEA/TCP re-broadcast off, no security) and the XDR attitude plugin in bench/signalk_plugin (Signal K's NMEA parser
has no XDR hook). Then
`ahrsd run --sim SCENARIO --nmea udp:<server> --nmea udp:<here>` runs, and this script reads Signal K's TCP delta
stream (the server's own output, after its parser and unit conversion) beside the same sentences as ahrsd sent
them. It prints, per Signal K path: the value pairs' largest difference, the update rates, and a few samples.
Signal K units: radians, radians per second; attitude roll positive to starboard, pitch positive bow up.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

# package.json names the server's version (2.23.0: the newest release whose engines field accepts Node.js 20);
# package-lock.json pins every package under it with its registry URL and hash (docs/marine.md: how to update it)
SERVER_PACKAGE_DIR = Path(__file__).resolve().parent / "signalk_server"
SIGNALK_SERVER_VERSION = json.loads((SERVER_PACKAGE_DIR / "package.json").read_text())["dependencies"]["signalk-server"]
PLUGIN_DIR = Path(__file__).resolve().parent / "signalk_plugin"
PATHS = ("navigation.headingTrue", "navigation.headingMagnetic", "navigation.rateOfTurn",
         "navigation.attitude")


class SignalKUnavailable(RuntimeError):
    """Node.js or the server package cannot be had here (the reason says which)."""


def cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "ahrsd" / "signalk-server"


def ensure_server(directory: Path | None = None, log=print) -> Path:
    """The signalk-server executable, installed into the cache on first use."""
    directory = directory or cache_dir()
    node = shutil.which("node")
    if node is None or shutil.which("npm") is None:
        raise SignalKUnavailable("Node.js and npm are not installed")
    major = int(subprocess.run([node, "--version"], capture_output=True, text=True).stdout.strip()
                .lstrip("v").split(".")[0] or 0)
    if major < 20:
        raise SignalKUnavailable(f"signalk-server {SIGNALK_SERVER_VERSION} needs Node.js ≥ 20 (found {major})")
    binary = directory / "node_modules" / ".bin" / "signalk-server"
    lockfile = (SERVER_PACKAGE_DIR / "package-lock.json").read_bytes()
    installed_lockfile = directory / "package-lock.json"
    if binary.exists() and installed_lockfile.exists() and installed_lockfile.read_bytes() == lockfile:
        return binary
    directory.mkdir(parents=True, exist_ok=True)
    log(f"installing signalk-server {SIGNALK_SERVER_VERSION} into {directory} (first use, about half a minute)")
    shutil.copyfile(SERVER_PACKAGE_DIR / "package.json", directory / "package.json")
    installed_lockfile.write_bytes(lockfile)
    # npm ci from the lockfile: no version resolution, for which `npm install` fetches and parses each package's
    # list of versions (docs/marine.md has what each option saves). --omit=optional: the server's optional
    # packages are plugins and web apps it runs without (chart plotter, instrument panel, serial ports, NMEA 2000
    # output).
    # --ignore-scripts: the install scripts build @canboat/canboatjs's SocketCAN addon with node-gyp (NMEA 2000
    # on a CAN bus; it prints "not available" and goes on where it cannot build) and run notices; the server
    # reads NMEA 0183 over UDP without them (tests/test_signalk.py runs it).
    done = subprocess.run(["npm", "ci", "--prefix", str(directory), "--omit=optional", "--ignore-scripts",
                           "--no-audit", "--no-fund", "--loglevel=error"],
                          capture_output=True, text=True, timeout=900)
    if done.returncode != 0 or not binary.exists():
        installed_lockfile.unlink(missing_ok=True)       # the next call installs again
        raise SignalKUnavailable("npm ci signalk-server failed: " + (done.stderr or done.stdout)[-400:])
    return binary


def free_port(kind=socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclass
class SignalKServer:
    """A signalk-server process with its own settings directory and an NMEA 0183 UDP input."""

    binary: Path
    http_port: int = field(default_factory=free_port)
    stream_port: int = field(default_factory=free_port)
    nmea_udp_port: int = field(default_factory=lambda: free_port(socket.SOCK_DGRAM))

    def __enter__(self) -> "SignalKServer":
        self._dir = tempfile.TemporaryDirectory(prefix="ahrsd-signalk-")
        config = Path(self._dir.name)
        settings = {
            "mdns": False,
            "ssl": False,
            "interfaces": {"nmea-tcp": False, "appstore": False, "mfd_webapp": False},
            "pipedProviders": [{
                "id": "ahrsd", "enabled": True,
                "pipeElements": [{"type": "providers/simple", "options": {
                    "logging": False, "type": "NMEA0183",
                    "subOptions": {"type": "udp", "port": str(self.nmea_udp_port)}}}]}],
        }
        (config / "settings.json").write_text(json.dumps(settings))
        (config / "package.json").write_text(json.dumps({"name": "ahrsd-signalk-config", "version": "0.0.0",
                                                         "dependencies": {"ahrsd-xdr-attitude": "*"}}))
        (config / "node_modules").mkdir()
        (config / "node_modules" / "ahrsd-xdr-attitude").symlink_to(PLUGIN_DIR, target_is_directory=True)
        (config / "plugin-config-data").mkdir()
        (config / "plugin-config-data" / "ahrsd-xdr-attitude.json").write_text(
            json.dumps({"enabled": True, "configuration": {}}))
        env = {**os.environ, "PORT": str(self.http_port), "TCPSTREAMPORT": str(self.stream_port),
               "TCPSTREAMADDRESS": "127.0.0.1", "SIGNALK_DISABLE_SERVER_UPDATES": "true",
               "SKIP_ADMINUI_VERSION_CHECK": "true"}
        self._log = open(config / "server.log", "w")
        self.process = subprocess.Popen([str(self.binary), "-c", str(config)], env=env, stdout=self._log,
                                        stderr=subprocess.STDOUT, cwd=config)
        self._wait_listening()
        return self

    def _wait_listening(self, timeout_s: float = 120.0) -> None:
        """Until the stream port greets with Signal K's hello: a bare accept could be another process that took
        the port between free_port() and the server's bind (the check would then read nothing from it)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise SignalKUnavailable("signalk-server exited at start: " + self.log_tail())
            with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", self.stream_port), 0.5) as s:
                s.settimeout(10.0)
                hello = s.makefile("rb").readline()
                try:
                    name = json.loads(hello).get("name")
                except (ValueError, AttributeError):
                    name = None
                if name != "signalk-server":
                    raise RuntimeError(f"port {self.stream_port} is not Signal K's stream: {hello[:200]!r}; "
                                       + self.log_tail())
                return
            time.sleep(0.2)
        raise SignalKUnavailable("signalk-server did not start listening in time: " + self.log_tail())

    def log_tail(self) -> str:
        self._log.flush()
        return (Path(self._dir.name) / "server.log").read_text()[-600:]

    def __exit__(self, *exc) -> None:
        self.process.terminate()
        try:
            self.process.wait(timeout=15)
        except subprocess.TimeoutExpired:
            self.process.kill()
        self._log.close()
        self._dir.cleanup()


class DeltaStream(threading.Thread):
    """Signal K's TCP delta stream, subscribed to PATHS: (arrival time, path, value) of every update.
    `lines`, `first_line` and `ended` say what came when no update did (a failed check prints them)."""

    def __init__(self, port: int):
        super().__init__(daemon=True)
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=5.0)
        subscribe = {"context": "vessels.self", "subscribe": [{"path": p, "policy": "instant"} for p in PATHS]}
        self.sock.sendall((json.dumps(subscribe) + "\r\n").encode())
        self.updates: list[tuple[float, str, object]] = []
        self.lines = 0
        self.first_line = b""
        self.ended = "running"
        self._stopping = threading.Event()      # not `_stop`: threading.Thread has a method of that name

    def run(self) -> None:
        try:
            self.ended = self._read()
        except Exception as exc:                 # noqa: BLE001 — said in the report instead of a thread traceback
            self.ended = f"reader failed: {exc!r}"

    def _read(self) -> str:
        buffer = b""
        self.sock.settimeout(0.5)
        while not self._stopping.is_set():
            try:
                chunk = self.sock.recv(65536)
            except socket.timeout:
                continue
            except OSError as exc:
                return "stopped" if self._stopping.is_set() else f"socket error {exc!r}"
            if not chunk:
                return "the server closed the stream"
            buffer += chunk
            *lines, buffer = buffer.split(b"\n")
            now = time.monotonic()
            for line in lines:
                self.lines += 1
                self.first_line = self.first_line or line[:200]
                with contextlib.suppress(ValueError):
                    delta = json.loads(line)
                    for update in delta.get("updates", ()) if isinstance(delta, dict) else ():
                        for value in update.get("values", ()):
                            if value.get("path") in PATHS:
                                self.updates.append((now, value["path"], value["value"]))
        return "stopped"

    def stop(self) -> None:
        self._stopping.set()
        self.sock.close()

    def describe(self) -> str:
        return f"stream: {self.lines} lines, first {self.first_line!r}, {self.ended}"


class SentTap(threading.Thread):
    """The sentences as ahrsd sent them (a second --nmea output to this socket), parsed by pynmeagps."""

    def __init__(self):
        super().__init__(daemon=True)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.5)
        self.port = self.sock.getsockname()[1]
        self.sentences: list[tuple[float, object]] = []
        self._stopping = threading.Event()      # not `_stop`: threading.Thread has a method of that name

    def run(self) -> None:
        from pynmeagps import NMEAReader

        while not self._stopping.is_set():
            try:
                data = self.sock.recv(200)
            except socket.timeout:
                continue
            except OSError:
                return
            self.sentences.append((time.monotonic(), NMEAReader.parse(data, validate=1)))

    def stop(self) -> None:
        self._stopping.set()
        self.sock.close()


def signal_k_value_of(msg) -> dict[str, object]:
    """What Signal K should make of one of ahrsd's sentences, computed here from the NMEA 0183 definitions."""
    rad = math.radians
    if msg.msgID == "HDT":
        return {"navigation.headingTrue": rad(float(msg.headingT))}
    if msg.msgID == "HDG":
        variation = float(msg.variation) * (1 if msg.variationEW == "E" else -1)
        deviation = float(msg.deviation) * (1 if msg.deviationEW == "E" else -1)
        magnetic = rad(float(msg.headingM) + deviation)
        return {"navigation.headingMagnetic": magnetic, "navigation.headingTrue": magnetic + rad(variation)}
    if msg.msgID == "ROT" and msg.valid == "A":
        return {"navigation.rateOfTurn": rad(float(msg.rot)) / 60.0}
    if msg.msgID == "XDR":
        return {"navigation.attitude": {"pitch": rad(float(msg.data_01)), "roll": rad(float(msg.data_02))}}
    return {}


def _difference(path: str, a, b) -> float:
    if path == "navigation.attitude":
        return max(abs(a.get(k, math.nan) - b[k]) for k in ("pitch", "roll"))
    diff = float(a) - float(b)
    if path.startswith("navigation.heading"):
        diff = (diff + math.pi) % (2 * math.pi) - math.pi
    return abs(diff)


@dataclass
class PathReport:
    path: str
    updates: int
    rate_hz: float
    matched: int
    max_difference: float
    example: tuple[object, object] | None
    rest: object = None                  # the value the REST API gave at the end of the run
    rest_difference: float = math.nan    # ... against the closest of ahrsd's sentences sent while listening
    sent: int = 0                        # ahrsd's sentences for this path while the stream was read
    run_notes: str = ""                  # the stream's state, ahrsd's exit and log tail (for a failure message)


# An update is one of ahrsd's sentences of the same kind sent from MATCH_BEFORE_S before its arrival to MATCH_AFTER_S
# after. Before: a server on a loaded machine delivers late (docs/testing.md, "Tests that ran the daemon in real time
# on a loaded machine"), never early. After: this process stamps the sentence (SentTap) and the update (DeltaStream)
# in two threads, and the tap's may come later. The match is exact (1e-6 rad against sentences in 0.1° steps, 10 a
# second, of a heading turning 5-13 °/s): a wrong unit, sign or variation finds no sentence of its value in a wider
# window either.
MATCH_BEFORE_S = 5.0
MATCH_AFTER_S = 1.0


def compare(updates, sentences, seconds: float, listened: tuple[float, float] = (-math.inf, math.inf)
            ) -> list[PathReport]:
    """Each Signal K update against ahrsd's sentences of that kind sent from MATCH_BEFORE_S before its arrival to
    MATCH_AFTER_S after: the closest value. `max_difference` is the worst of those: what Signal K changed in a value
    (units, signs, rounding); `matched` counts the updates with a sentence in the window; `sent` counts ahrsd's
    values for the path sent while the stream was read (`listened`, monotonic seconds from and to)."""
    sent_by_path: dict[str, list[tuple[float, object]]] = {p: [] for p in PATHS}
    for t, msg in sentences:
        for path, value in signal_k_value_of(msg).items():
            sent_by_path[path].append((t, value))
    reports = []
    for path in PATHS:
        ups = [(t, v) for t, p, v in updates if p == path]
        sent = sent_by_path[path]
        worst, matched, example = 0.0, 0, None
        for t, value in ups:
            near = [v for ts, v in sent if -MATCH_BEFORE_S <= ts - t <= MATCH_AFTER_S]
            if not near:
                continue
            best = min(near, key=lambda v: _difference(path, value, v))
            worst, matched = max(worst, _difference(path, value, best)), matched + 1
            example = example or (value, best)
        span = (ups[-1][0] - ups[0][0]) if len(ups) > 1 else math.nan
        sent_while_listening = sum(1 for ts, _ in sent if listened[0] <= ts <= listened[1])
        reports.append(PathReport(path, len(ups), (len(ups) - 1) / span if span > 0 else 0.0, matched, worst,
                                  example, sent=sent_while_listening))
    return reports


def run_check(seconds: float = 30.0, scenario: str = "level-turns", log=print, min_updates: int = 0,
              max_seconds: float = 120.0) -> list[PathReport]:
    """Listen `seconds`, then on until every path has `min_updates` updates (at most `max_seconds` in all): on a
    loaded machine the server's stream can take seconds of a short window to start, and a count, not a wall-clock
    share, says whether each path came at its rate (the rate is taken from the updates' own span)."""
    binary = ensure_server(log=log)
    with SignalKServer(binary) as server:
        tap = SentTap()
        tap.start()
        with tempfile.TemporaryDirectory(prefix="ahrsd-signalk-state-") as state:
            from bench.sim_calibration import save_mag_calibration, sim_chip_mag_model

            save_mag_calibration(state, sim_chip_mag_model(scenario))   # without it (and GNSS) no heading is sent
            # ahrsd's log to a file: a pipe nobody reads would stop the daemon once it held 64 KiB
            ahrsd_log_path = Path(state) / "ahrsd-stderr.log"
            with open(ahrsd_log_path, "w") as ahrsd_log:
                ahrsd = subprocess.Popen(
                    [sys.executable, "-m", "ahrsd.cli", "run", "--sim", scenario, "--no-log", "--status-line", "off",
                     "--state-dir", state, "--mavlink", f"udpout:127.0.0.1:{free_port(socket.SOCK_DGRAM)}",
                     "--nmea", f"udp:127.0.0.1:{server.nmea_udp_port}", "--nmea", f"udp:127.0.0.1:{tap.port}"],
                    stdout=subprocess.DEVNULL, stderr=ahrsd_log)
            try:
                deadline = time.monotonic() + 300.0          # a first start compiles the estimator
                while not any(m.msgID == "HDT" for _, m in tap.sentences):
                    if ahrsd.poll() is not None or time.monotonic() > deadline:
                        raise RuntimeError("ahrsd sent no heading: " + ahrsd_log_path.read_text()[-600:])
                    time.sleep(0.2)
                stream = DeltaStream(server.stream_port)
                stream.start()
                listen_from = time.monotonic()
                time.sleep(seconds)
                while (min(sum(1 for _, p, _ in list(stream.updates) if p == path) for path in PATHS) < min_updates
                       and time.monotonic() - listen_from < max_seconds and ahrsd.poll() is None):
                    time.sleep(0.5)
                rest_at = time.monotonic()
                rest = rest_navigation(server.http_port)
                rest_answered = time.monotonic()     # a loaded server can answer seconds after the request
                stream.stop()
                ahrsd_exit = ahrsd.poll()
                run_notes = (f"listened {rest_at - listen_from:.1f} s; {stream.describe()}; ahrsd "
                             + ("running" if ahrsd_exit is None else f"exited {ahrsd_exit}")
                             + "; ahrsd's last log lines: " + " | ".join(
                                 ahrsd_log_path.read_text(errors="replace").splitlines()[-6:])
                             + "; server log: " + server.log_tail()[-300:])
            finally:
                ahrsd.terminate()
                try:
                    ahrsd.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    ahrsd.kill()
        tap.stop()
    reports = compare(stream.updates, tap.sentences, seconds, listened=(listen_from, rest_at))
    for r in reports:
        r.rest = rest_value(rest, r.path)
        r.rest_difference = rest_difference(r.path, r.rest, tap.sentences, listen_from, rest_answered)
        r.run_notes = run_notes
    return reports


def rest_navigation(http_port: int) -> dict:
    """GET /signalk/v1/api/vessels/self/navigation: what a Signal K client reads (values and their time stamps)."""
    import urllib.request

    url = f"http://127.0.0.1:{http_port}/signalk/v1/api/vessels/self/navigation"
    with urllib.request.urlopen(url, timeout=10) as answer:
        return json.load(answer)


def rest_value(navigation: dict, path: str):
    node = navigation.get(path.split(".", 1)[1], {})
    return node.get("value") if isinstance(node, dict) else None


def rest_difference(path: str, value, sentences, since: float, at: float) -> float:
    """The REST value against ahrsd's sentences of that kind sent from `since` (the stream's start) until `at`
    (the answer came). Not only the last MATCH_BEFORE_S before the request: on a loaded machine the value Signal K
    serves can be seconds from the request's time (docs/marine.md); a wrong unit or sign matches none of them
    either way."""
    if value is None:
        return math.nan
    near = [v for t, msg in sentences if since <= t <= at + 0.2
            for p, v in signal_k_value_of(msg).items() if p == path]
    return min((_difference(path, value, v) for v in near), default=math.nan)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--scenario", default="level-turns")
    args = parser.parse_args(argv)
    try:
        reports = run_check(args.seconds, args.scenario)
    except SignalKUnavailable as exc:
        print(f"Signal K check not run: {exc}", file=sys.stderr)
        return 2
    print(f"signalk-server {SIGNALK_SERVER_VERSION}, ahrsd --sim {args.scenario}, {args.seconds:g} s, "
          "NMEA 0183 over UDP (default rates HDT/HDG 10 Hz, ROT/XDR 5 Hz)")
    print(f"{'Signal K path':30s} {'updates':>8s} {'rate Hz':>8s} {'matched':>8s} {'max |SK - ahrsd|':>18s}  "
          "REST value  |REST - ahrsd|")
    for r in reports:
        unit = "rad/s" if r.path.endswith("rateOfTurn") else "rad"
        print(f"{r.path:30s} {r.updates:8d} {r.rate_hz:8.2f} {r.matched:8d} {r.max_difference:14.2e} {unit:5s}"
              f"  {r.rest}  {r.rest_difference:.1e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
