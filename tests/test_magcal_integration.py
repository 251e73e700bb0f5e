"""End to end: the daemon (Service + the mag-cal handler) in a subprocess on the simulated level-turns boat with
the simulator's default vehicle iron, driven over UDP by pymavlink and by MAVProxy's `magcal` module (MAVProxy's
daemon on a thread of this process: what that test checks is MAVProxy's side of the protocol; the daemon as a
process, its stop and its restart with the saved calibration are the pymavlink session's).
With signing configured an unsigned mag-cal start is refused: the router's rule for the mag-cal commands in
tests/test_magcal_protocol.py (test_router_ignores_broadcast_unless_configured_and_refuses_unsigned), the daemon's
signing of its commands end to end in tests/test_integration_tools.py (test_notify_watchdog_and_signing).

Speed: the simulated ADIS16405 chip is read in real time, and a session needs 1.5 turns of a 40 s turn
(~60 s of simulated time). To stay inside the test budget the daemon here reads the same simulator
(`open_stream("level-turns", seed=0)`: scenario, ADIS16405 error model, default vehicle iron) through the
daemon's ReplaySource paced by a clock running TIME_SCALE times faster than real time; everything after the
source (calibration, estimator, MAVLink, the mag-cal protocol, the store) is the daemon's own code.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from scipy.linalg import polar
from scipy.spatial.transform import Rotation


from ahrsd.calibration.ardupilot_compass import from_ardupilot  # noqa: E402
from ahrsd.core.angles import tilt_compensated_heading_rad  # noqa: E402
from ahrsd.calibration.models import Calibration  # noqa: E402
from service_rig import free_udp_port  # noqa: E402
from support.magcal_client import REPLY_LIMIT_S, STARTING_LIMIT_S, Client  # noqa: E402
from support.thread_daemon import ThreadDaemon  # noqa: E402
from ahrsd.calibration.store import CalibrationStore  # noqa: E402
from ahrsd.daemon.commands import DUPLICATE_WINDOW_S  # noqa: E402
from ahrsd.daemon.mavlink_io import mavlink  # noqa: E402
from ahrsd.simulation import DEFAULT_SITE, open_stream  # noqa: E402

pytestmark = pytest.mark.slow     # a long file: started first under pytest-xdist (tests/conftest.py)

TIME_SCALE = 16.0  # when the CPU cannot keep up the replay simply runs as fast as it can
SIM_RATE_HZ = 102.4   # the chip's 819.2 SPS decimated by 8 (SMPL_PRD 7): an eighth of the CPU per simulated second
MAV_STATE_CALIBRATING = 2
SESSION_LIMIT_S = 180.0  # start to MAG_CAL_REPORT: ~60 s of turning at TIME_SCALE plus the fit in its worker process

# The daemon's set-up from `a` (Daemon's arguments): run as a process (LAUNCH) or on a thread of this process
# (support/thread_daemon.py)
SETUP = r"""
import asyncio, json, logging, sys, time
from ahrsd.daemon.config import Config, OutputsConfig
from ahrsd.drivers.replay_source import ReplaySource
from ahrsd.daemon.service import Service
from ahrsd.daemon.magcal_settings import settings_from_mapping
from ahrsd.core.sample import make_sample, SampleFlags
from ahrsd.simulation import open_stream
import dataclasses
cfg = Config().with_overrides(sim=a["sim"], mavlink=[a["url"]], state_dir=a["state_dir"])
if a.get("outputs"):
    cfg = dataclasses.replace(cfg, outputs=OutputsConfig.parse(a["outputs"]))
scale = float(a["time_scale"])
t0 = time.monotonic()
def clock():
    return t0 + scale * (time.monotonic() - t0)
def samples():
    stream = open_stream(a["sim"], rate_hz=a["rate_hz"], seed=0)
    k = 0
    while True:
        b = stream.next_block(int(a["rate_hz"] / 2))
        for i in range(len(b.t_s)):
            yield make_sample(b.t_s[i], b.gyro_rad_s[i], b.accel_m_s2[i], b.mag_ut[i], temp_c=float(b.temp_c[i]),
                              counter=k, flags=SampleFlags.NEW_DATA)
            k += 1
cfg = dataclasses.replace(cfg, magcal=settings_from_mapping(a.get("magcal")))
service = Service(cfg, source=ReplaySource(samples(), "simulator " + a["sim"], realtime=True, clock=clock,
                                           rate_hz=a["rate_hz"]))
"""
LAUNCH = r"""
import json, logging, sys
logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
a = json.loads(sys.argv[1])
""" + SETUP + r"""
# ended as `ahrsd run` ends (cli/main.py): past the interpreter's teardown (docs/daemon.md "Stopping")
from ahrsd.cli.main import exit_stopped_daemon
exit_stopped_daemon(asyncio.run(service.run()))
"""


class Daemon:
    """The daemon as a process (LAUNCH); with in_thread, on a thread of this process (ThreadDaemon: the same set-up,
    no interpreter, imports and kernel loads of its own) for a test whose check is not the process."""

    def __init__(self, state_dir: Path, port: int, magcal: dict | None = None,
                 log_path: Path | None = None, outputs: dict | None = None, in_thread: bool = False):
        args = {"sim": "level-turns", "url": f"udpout:127.0.0.1:{port}", "state_dir": str(state_dir),
                "time_scale": TIME_SCALE, "rate_hz": SIM_RATE_HZ, "magcal": magcal or {}, "outputs": outputs or {}}
        self.log_path = log_path or state_dir.parent / f"daemon-{port}.log"
        self.thread = ThreadDaemon(SETUP, args, self.log_path) if in_thread else None
        if self.thread is not None:
            return
        self.log = open(self.log_path, "a")
        self.proc = subprocess.Popen([sys.executable, "-c", LAUNCH, json.dumps(args)], stderr=self.log,
                                     stdout=subprocess.DEVNULL)

    def stop(self) -> None:
        if self.thread is not None:
            self.thread.stop()
            return
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.log.close()

    def text(self) -> str:
        return self.log_path.read_text()


STARTED_LINE = "ahrsd started"    # daemon.service logs it when the loop is about to run
HEARTBEAT_AFTER_START_S = 20.0     # the first HEARTBEAT is due 1 s into the loop; 20 s is for a loaded machine


def first_heartbeat(c: Client, daemon: Daemon):
    """Our first HEARTBEAT, HEARTBEAT_AFTER_START_S at most after the daemon's start line. Before that line it
    may be compiling the estimator (run without -n, conftest's numba warm-up does not run: a fresh checkout
    compiles in the daemon, 22 s at load 1-3 and 53 s at load 8 in the README), so it is waited for while the
    process lives, up to STARTING_LIMIT_S. A daemon that exits fails at once."""
    end = time.monotonic() + STARTING_LIMIT_S
    started_at = None
    while time.monotonic() < end:
        hb = c.wait(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 200, 1.0)
        if hb is not None:
            return hb
        assert daemon.proc.poll() is None, f"the daemon exited ({daemon.proc.returncode}): {daemon.text()[-2000:]}"
        if started_at is None and STARTED_LINE in daemon.text():
            started_at = time.monotonic()
        if started_at is not None and time.monotonic() - started_at > HEARTBEAT_AFTER_START_S:
            break
    state = "started" if started_at is not None else f"not started after {STARTING_LIMIT_S:.0f} s"
    raise AssertionError(f"no HEARTBEAT from the daemon ({state}): {daemon.text()[-2000:]}")


def truth_models():
    e = open_stream("level-turns", seed=0).errors
    return e.hard_iron_ut, np.linalg.inv(e.soft_iron)


def heading_error_rms_deg(cal: Calibration, seconds: float = 80.0) -> float:
    """Tilt-compensated heading from the calibrated simulator field vs the true magnetic heading (the truth
    attitude's heading, scipy, minus the site's declination), over a fresh stretch of level turns (another
    noise seed), truth roll/pitch."""
    stream = open_stream("level-turns", seed=7, start_s=300.0)
    b = stream.next_block(int(seconds * 819.2))
    sl = slice(None, None, 41)   # 20 Hz is plenty
    rpy = Rotation.from_quat(b.truth_q_wxyz[sl][:, [1, 2, 3, 0]]).as_euler("ZYX")
    roll, pitch = rpy[:, 2], rpy[:, 1]
    psi = tilt_compensated_heading_rad(cal.mag.apply(b.mag_ut[sl]), roll, pitch)
    psi_true = rpy[:, 0] - DEFAULT_SITE.earth_field().declination_rad
    err = np.angle(np.exp(1j * (psi - psi_true)))
    return float(np.degrees(np.sqrt(np.mean(err**2))))


@pytest.fixture
def daemon_env(tmp_path):
    port = free_udp_port()
    state = tmp_path / "state"
    daemons: list[Daemon] = []

    def start(**kw) -> Daemon:
        d = Daemon(state, port, **kw)
        daemons.append(d)
        return d

    yield port, state, start
    for d in daemons:
        d.stop()


def test_full_session_with_pymavlink(daemon_env):
    port, state, start = daemon_env
    # a faster heading slew than the default 2 °/s so the swap completes within the test budget
    daemon = start(outputs={"heading_slew_deg_s": 20.0})
    c = Client(port)
    first_heartbeat(c, daemon)
    c.wait(lambda m: m.get_type() == "HIGHRES_IMU", 10)
    mean_before, spread_before = c.mag_norm_spread_ut(2.0)

    # broadcast mag-cal commands are ignored by default (they would start the autopilot's calibration too)
    assert c.command(42424, 0, 0, 0, 0, 0, target=(1, 0), timeout=1.5) is None
    # refused while the autopilot reports armed
    c.autopilot_heartbeat(armed=True)
    time.sleep(0.3)
    n = len(c.msgs)
    ack = c.command(42424)
    assert ack is not None and ack.result == mavlink.MAV_RESULT_TEMPORARILY_REJECTED
    # the STATUSTEXT may come before the ACK: looked for among what came since the command too
    assert c.seen_or_wait(lambda m: m.get_type() == "STATUSTEXT" and "Disarm to allow compass calibration" in m.text,
                          REPLY_LIMIT_S, n) is not None
    c.autopilot_heartbeat(armed=False)
    time.sleep(0.3)
    # start, a second start while running (no effect), cancel
    assert c.command(42424).result == mavlink.MAV_RESULT_ACCEPTED
    first_start_acked = time.monotonic()
    p1 = c.wait(lambda m: m.get_type() == "MAG_CAL_PROGRESS", REPLY_LIMIT_S)
    assert p1 is not None and p1.cal_status in (1, 2)
    c.wait(lambda m: False, 1.0)
    n = len(c.msgs)
    assert c.command(42424, 0, 1, 1, 0).result == mavlink.MAV_RESULT_ACCEPTED
    assert c.seen_or_wait(lambda m: m.get_type() == "STATUSTEXT" and "already running" in m.text,
                          REPLY_LIMIT_S, n) is not None
    assert c.command(42426).result == mavlink.MAV_RESULT_ACCEPTED
    n = len(c.msgs)
    c.wait(lambda m: False, 1.0)
    assert not c.of("MAG_CAL_PROGRESS", n)

    # the real session. Its start is the first start's command again: sent within the daemon's DUPLICATE_WINDOW_S
    # of that one's ACK it would be answered as a re-sent duplicate (ACCEPTED, not executed)
    c.wait(lambda m: False, first_start_acked + DUPLICATE_WINDOW_S + 0.5 - time.monotonic())
    t0 = time.monotonic()
    assert c.command(42424, 0, 0, 0, 0, 0).result == mavlink.MAV_RESULT_ACCEPTED
    c.wait(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 200
           and m.system_status == MAV_STATE_CALIBRATING, REPLY_LIMIT_S)
    n = len(c.msgs)
    report = c.wait(lambda m: m.get_type() == "MAG_CAL_REPORT", SESSION_LIMIT_S)
    assert report is not None, daemon.text()[-3000:]
    wall = time.monotonic() - t0
    # HIGHRES_IMU.time_usec carries the sample time here (ReplaySource: no phase lock), i.e. simulated time; the
    # span from the start to the report also holds the final fit's wall-clock time TIME_SCALE times over (the
    # replay goes on while the fit runs in its worker), so it is printed, and the turning the session needed is
    # taken from the saved calibration's data span below
    imu = c.of("HIGHRES_IMU", n)
    sim_s = (imu[-1].time_usec - imu[0].time_usec) * 1e-6
    pcts = [m.completion_pct for m in c.of("MAG_CAL_PROGRESS", n)]
    assert pcts == sorted(pcts) and max(pcts) >= 95
    assert report.cal_status == 4, [m.text for m in c.of("STATUSTEXT")]
    assert report.autosaved == 0 and 0 < report.fitness < 16
    fitted = from_ardupilot([report.ofs_x, report.ofs_y, report.ofs_z], [report.diag_x, report.diag_y, report.diag_z],
                            [report.offdiag_x, report.offdiag_y, report.offdiag_z], report.scale_factor)
    hard_true, soft_true = truth_models()
    _, sym_true = polar(soft_true, side="right")
    print(f"\nsession: report {sim_s:.0f} s of simulated time after the start ({wall:.1f} s wall), "
          f"fitness {report.fitness:.2f} mG")
    print(f"  hard iron fitted {np.round(fitted.hard_iron_ut, 2)} uT, injected {np.round(hard_true, 2)} uT")
    print(f"  soft iron (symmetric part) fitted {np.round(fitted.soft_iron, 3).tolist()}")
    print(f"                           true   {np.round(sym_true, 3).tolist()}")
    assert np.linalg.norm(fitted.hard_iron_ut - hard_true) < 1.0
    assert np.allclose(fitted.soft_iron, sym_true, atol=0.03)

    # accept: saved atomically, applied without restart
    n_accept = len(c.msgs)
    assert c.accept_calibration().result == mavlink.MAV_RESULT_ACCEPTED
    assert c.seen_or_wait(lambda m: m.get_type() == "STATUSTEXT" and "saved" in m.text, REPLY_LIMIT_S,
                          n_accept) is not None
    saved = CalibrationStore(state).load()
    assert np.allclose(saved.mag.hard_iron_ut, fitted.hard_iron_ut, atol=1e-3)
    # the session's samples, first to last (sample time: the session takes none while its fit runs)
    data_t0_s, data_t1_s = saved.metadata["mag"]["data_span_s"]
    print(f"  the session's data: {data_t1_s - data_t0_s:.0f} s of simulated turning")
    assert data_t1_s - data_t0_s < 120.0                # within two minutes of simulated turning
    done = c.seen_or_wait(lambda m: m.get_type() == "STATUSTEXT" and "fully applied" in m.text, 60, n_accept)
    assert done is not None, daemon.text()[-2000:]
    mean_after, spread_after = c.mag_norm_spread_ut(2.0)
    before = heading_error_rms_deg(Calibration.identity())
    after = heading_error_rms_deg(saved)
    print(f"  |mag| {mean_before:.1f}±{spread_before:.1f} uT before, {mean_after:.1f}±{spread_after:.2f} uT after")
    print(f"  heading error RMS before {before:.2f} deg, after {after:.2f} deg")
    assert spread_after < spread_before / 5
    assert after < 1.5 and after < before / 10
    daemon.stop()
    assert "magnetometer calibration changed" in daemon.text() and "before:" in daemon.text()

    # restart: the new calibration is in force. The first daemon's last messages wait in the socket (the client
    # read none while the heading errors were computed): dropped, so that only the second daemon's are judged
    c.drop_queued()
    daemon2 = start()
    first_heartbeat(c, daemon2)
    c.wait(lambda m: m.get_type() == "HIGHRES_IMU", REPLY_LIMIT_S)
    mean_restart, spread_restart = c.mag_norm_spread_ut(2.0)
    assert spread_restart < spread_before / 5 and abs(mean_restart - mean_after) < 1.0, daemon2.text()[-2000:]


def test_session_driven_by_mavproxy(daemon_env, tmp_path):
    mavproxy = shutil.which("mavproxy.py", path=os.path.dirname(sys.executable)) or shutil.which("mavproxy.py")
    if mavproxy is None:
        pytest.skip("MAVProxy (mavproxy.py) is not installed")
    port, state, start = daemon_env
    daemon = start(magcal={"accept_broadcast": True}, outputs={"heading_slew_deg_s": 20.0}, in_thread=True)
    # --target-system: with no autopilot on the link MAVProxy has no target system and would not hand our
    # messages to its modules (with an autopilot it targets the autopilot's system, which ahrsd latches).
    mp = subprocess.Popen([sys.executable, mavproxy, f"--master=udpin:127.0.0.1:{port}", "--nowait",
                           "--target-system=1", "--target-component=200",
                           "--default-modules=calibration", f"--state-basedir={tmp_path / 'mavproxy'}"],
                          stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                          bufsize=1)
    lines: list[str] = []
    threading.Thread(target=lambda: lines.extend(line.rstrip() for line in mp.stdout), daemon=True).start()
    try:
        end = time.monotonic() + STARTING_LIMIT_S     # the daemon's start and MAVProxy's, side by side
        while time.monotonic() < end and not any("Detected vehicle" in x for x in lines):
            time.sleep(0.2)
        assert any("Detected vehicle 1:200" in x for x in lines), lines[-20:]
        mp.stdin.write("magcal start\n")   # MAVProxy: target_component 0, autosave 1; accepts on the report
        mp.stdin.flush()
        end = time.monotonic() + SESSION_LIMIT_S
        while time.monotonic() < end and not any("Calibration of compass" in x for x in lines):
            time.sleep(0.3)
        time.sleep(1.0)
    finally:
        mp.kill()
        mp.wait()
    out = "\n".join(lines)
    assert "DO_START_MAG_CAL: ACCEPTED" in out, out[-3000:]
    assert "Calibration of compass 0 SUCCESS" in out, out[-3000:] + daemon.text()[-3000:]
    assert "Mag cal saved" in out
    saved = CalibrationStore(state).load()
    hard_true, _ = truth_models()
    assert np.linalg.norm(saved.mag.hard_iron_ut - hard_true) < 1.0
    assert saved.metadata["mag"]["method"] == "field:backstepping"


POWER_LOSS = r"""
import os, signal, sys
import numpy as np
from types import SimpleNamespace
sys.path.insert(0, sys.argv[2])
from support.field_data import level_turns
from support.magcal_host import FakeHost, Clock, cmd, drive
from ahrsd.daemon.magcal import MagCalProtocol, MagCalSettings
import ahrsd.calibration.store as store

host = FakeHost(sys.argv[1])
clock = Clock()
proto = MagCalProtocol(host, MagCalSettings(vehicle_type="level"), clock=clock, fit_in_process=False)  # fits in a thread: no worker to spawn
proto.handle_start(cmd(42424))
drive(proto, clock, level_turns(), host, until=lambda: proto.session.status == 4)
real_replace = os.replace
def replace(src, dst):
    if str(dst).endswith(store.CURRENT_NAME):
        print("killed between write and rename", flush=True)
        os.kill(os.getpid(), signal.SIGKILL)   # power loss: the new file is written and fsynced, not renamed
    return real_replace(src, dst)
os.replace = replace
proto.handle_accept(cmd(42425))
print("not reached")
"""


def test_power_loss_during_save_keeps_previous_calibration(tmp_path):
    from ahrsd.calibration.models import MagModel

    state = tmp_path / "state"
    old = Calibration.identity().with_sensor("mag", MagModel(np.array([1.0, 2.0, 3.0]), np.eye(3)), method="bench")
    CalibrationStore(state).save(old)
    out_path = tmp_path / "power-loss.out"
    with open(out_path, "w") as out:
        r = subprocess.run([sys.executable, "-c", POWER_LOSS, str(state), str(Path(__file__).parent)],
                           stdout=out, stderr=subprocess.STDOUT, timeout=60)
    text = out_path.read_text()
    assert r.returncode == -signal.SIGKILL, text
    assert "killed between write and rename" in text
    store = CalibrationStore(state)
    loaded = store.load()
    assert np.array_equal(loaded.mag.hard_iron_ut, old.mag.hard_iron_ut)   # the previous calibration is intact
    assert store.last_load.source == "current" and not store.last_load.problems
