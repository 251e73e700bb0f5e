"""Whole field sessions through the daemon over MAVLink (UDP, pymavlink as the ground station) on simulated
level vehicles at ±2° and ±30° of tilt with strong non-symmetric iron (tests/support/field_vehicle.py), the
saved calibration scored on attitudes the session never saw against the injected iron; and a session during
which the "autopilot" sends GPS_RAW_INT course made from the simulation truth. The tilts in between take the
same path (no branch of the session below its 60° tumble threshold): ±10° is in-process in
tests/test_field_session_vehicles.py, which runs the same session and offline fit at ±2°, ±10° and ±30°.

The daemon runs on a thread of this process (tests/support/thread_daemon.py) and reads the recording through its ReplaySource,
paced by a clock running TIME_SCALE times faster than real time; everything after the source (calibration,
estimator, MAVLink, the mag-cal protocol, its fit worker process, the store) is the daemon's own code.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("ahrsd.daemon.service")

from ahrsd.calibration.mag.offsets import fit_offsets_keep_soft_iron  # noqa: E402
from ahrsd.calibration.models import MagModel  # noqa: E402
from ahrsd.calibration.store import CalibrationStore  # noqa: E402
from ahrsd.core.sample import make_sample  # noqa: E402
from ahrsd.daemon.mavlink_io import mavlink  # noqa: E402
from ahrsd.drivers.recording import RecordingWriter  # noqa: E402
from ahrsd.simulation import DEFAULT_SITE  # noqa: E402

from support.field_vehicle import RATE_HZ as FIELD_RATE_HZ  # noqa: E402
from support.field_vehicle import (SITE_FIELD, course_fixes, heading_rms_deg, injected_iron, record, truth_euler,  # noqa: E402
                          vehicle)
from service_rig import free_udp_port  # noqa: E402
from support.magcal_client import STARTING_LIMIT_S, Client  # noqa: E402
from support.thread_daemon import ThreadDaemon  # noqa: E402

pytestmark = pytest.mark.slow     # a long file: started first under pytest-xdist (tests/conftest.py)

RECORDING_S = 300.0
GATE_STALL_S = 10.0        # wall seconds the replay waits for the daemon to take a fix before it moves on

# The daemon's set-up, run on a thread of this process (support/thread_daemon.py) with `a`, start_daemon's
# arguments, in its namespace; the thread then runs `service`
LAUNCH = r"""
import asyncio, dataclasses, json, logging, os, sys, time
from support.field_vehicle import RATE_HZ, record, vehicle
from ahrsd.core.sample import SampleFlags, make_sample
from ahrsd.daemon.config import Config, OutputsConfig
from ahrsd.daemon.magcal_settings import settings_from_mapping
from ahrsd.drivers.replay_source import ReplaySource
from ahrsd.daemon.service import Service
links = [a["url"]] + ([f"udpin:127.0.0.1:{a['autopilot']['port']}"] if a.get("autopilot") else [])
cfg = Config().with_overrides(sim="level-turns", mavlink=links, state_dir=a["state_dir"])
cfg = dataclasses.replace(cfg, outputs=OutputsConfig.parse({"highres_imu_hz": a["highres_imu_hz"]}))
block = record(vehicle(a["tilt_deg"], a["straight_runs"]), a["seconds"])
def samples():
    for i in range(len(block.t_s)):
        yield make_sample(block.t_s[i], block.gyro_rad_s[i], block.accel_m_s2[i], block.mag_ut[i], counter=i,
                          flags=SampleFlags.NEW_DATA)
scale = float(a["time_scale"])
t0 = time.monotonic()
ap = a.get("autopilot")     # an autopilot sending GPS_RAW_INT over its own MAVLink link, or None
log = logging.getLogger("test.autopilot")
ap_state = {"k": 0, "waiting": False, "count": 0, "sent_at": 0.0, "sent": 0, "taken": 0, "late_s": 0.0,
            "timeouts": 0, "last": -float("inf")}
def send_fix(k):
    link.mav.gps_raw_int_send(ap["valid_usec"][k], 3, ap["lat_e7"], ap["lon_e7"], ap["alt_mm"], 80, 120,
                              ap["speed_cm_s"][k], ap["course_cdeg"][k], 12)
    ap_state["sent"] += 1
def save_stats():
    with open(ap["stats_file"] + ".tmp", "w") as f:
        json.dump(ap_state, f)
    os.replace(ap["stats_file"] + ".tmp", ap["stats_file"])
def autopilot_gate(now):
    # Fix k is sent when the replayed samples reach its arrival time; while a session runs, the recording then
    # waits there until the daemon has taken the fix (course_fed + course_unusable counts every GPS_RAW_INT of
    # a session), so it is stamped with the sample of its arrival whatever the machine's load. Before a
    # session the daemon ignores the fixes, as it would a live autopilot's.
    last = service.pipeline.last_sample if service.pipeline is not None else None
    if last is None:
        return now
    arrival = ap["arrival_s"]
    hold = lambda t_s: min(now, t_s + 1e-6 + replay.monotonic_offset_s)
    m = service.magcal
    running = m is not None and m.calibrating
    n = m.course_fed + m.course_unusable if m is not None else 0
    if ap_state["waiting"]:
        k = ap_state["k"] - 1
        if n > ap_state["count"]:
            ap_state["waiting"], ap_state["taken"] = False, ap_state["taken"] + 1
            ap_state["late_s"] = max(ap_state["late_s"], last.t_s - arrival[k])
            save_stats()
        elif running and time.monotonic() - ap_state["sent_at"] > a["gate_stall_s"]:
            log.warning("fix %d at t=%.3f not taken in %.0f s: moving on", k, arrival[k], a["gate_stall_s"])
            ap_state["waiting"], ap_state["timeouts"] = False, ap_state["timeouts"] + 1
            save_stats()
        elif running:
            return hold(arrival[k])
        else:
            ap_state["waiting"] = False
    k = ap_state["k"]
    while k < len(arrival) and arrival[k] <= last.t_s + 1e-6:
        send_fix(k)
        k += 1
        ap_state["k"] = k
        if running:
            ap_state["waiting"], ap_state["count"], ap_state["sent_at"] = True, n, time.monotonic()
            return hold(arrival[k - 1])
    return hold(arrival[k]) if k < len(arrival) else now
def clock():
    now = t0 + scale * (time.monotonic() - t0)
    if ap is not None:
        now = autopilot_gate(now)
    ap_state["last"] = max(ap_state["last"], now)      # a clock never runs backwards
    return ap_state["last"]
cfg = dataclasses.replace(cfg, magcal=settings_from_mapping(a.get("magcal")))
if ap is not None:
    from pymavlink import mavutil
    link = mavutil.mavlink_connection(f"udpout:127.0.0.1:{ap['port']}", source_system=1, source_component=1)
replay = ReplaySource(samples(), "field-calibration vehicle", realtime=True, rate_hz=RATE_HZ, clock=clock)
service = Service(cfg, source=replay)
"""


def start_daemon(tmp_path: Path, port: int, tilt_deg: float, straight_runs: bool, time_scale: float,
                 magcal: dict | None = None, highres_imu_hz: float = 50.0, autopilot: dict | None = None):
    """The daemon replaying the vehicle TIME_SCALE times faster than real time, its MAVLink to `port`; with
    `autopilot` (autopilot_gps_raw_int), an autopilot on a second link sends GPS_RAW_INT from inside the
    daemon's process, each fix when the replay reaches its arrival time."""
    args = {"url": f"udpout:127.0.0.1:{port}", "state_dir": str(tmp_path / "state"), "tilt_deg": tilt_deg,
            "straight_runs": straight_runs, "seconds": RECORDING_S, "time_scale": time_scale,
            "magcal": magcal or {}, "highres_imu_hz": highres_imu_hz, "tests_dir": str(Path(__file__).parent),
            "autopilot": autopilot, "gate_stall_s": GATE_STALL_S}
    return ThreadDaemon(LAUNCH, args, tmp_path / "daemon.log")


def run_session(client: Client, on_imu=None, timeout_s: float = 120.0):
    """Start, wait for the report (calling on_imu(msg) for every HIGHRES_IMU meanwhile), accept; returns the
    report and the STATUSTEXT lines."""
    assert client.wait(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 200, STARTING_LIMIT_S) is not None
    n = len(client.msgs)
    assert client.command(42424).result == mavlink.MAV_RESULT_ACCEPTED
    end = time.monotonic() + timeout_s
    report = None
    while time.monotonic() < end and report is None:
        m = client.wait(lambda m: m.get_type() in ("MAG_CAL_REPORT", "HIGHRES_IMU"), 1.0)
        if m is None:
            continue
        if m.get_type() == "MAG_CAL_REPORT":
            report = m
        elif on_imu is not None:
            on_imu(m)
    assert report is not None, [m.text for m in client.of("STATUSTEXT", n)]
    if report.cal_status == mavlink.MAG_CAL_SUCCESS and not _said_accuracy(client.of("STATUSTEXT", n)):
        # the session says its accuracy in the tick that ends it; the text may come after the report (the
        # STATUSTEXT queue is paced), later still on a busy machine: wait for it rather than read too early
        client.wait(lambda m: _said_accuracy([m]), ACCURACY_TEXT_WAIT_S)
    assert client.accept_calibration().result == mavlink.MAV_RESULT_ACCEPTED
    return report, [m.text for m in client.of("STATUSTEXT", n)]


ACCURACY_TEXT_WAIT_S = 30.0


def _said_accuracy(msgs) -> bool:
    return any(m.get_type() == "STATUSTEXT" and m.text.startswith("Mag cal: heading") for m in msgs)


def offline_backstepping(tmp_path: Path, block, sel) -> MagModel:
    """`ahrsd calibrate mag --method backstepping RECORDING --lat --lon --alt-m --date` (in this process) on
    the selected samples written as an `ahrsd record` CSV; the fitted model from its --json output."""
    from ahrsd.cli.main import main

    path = tmp_path / "session-stretch.csv"
    with RecordingWriter(path) as w:
        for i in np.flatnonzero(sel):
            w.write(make_sample(block.t_s[i], block.gyro_rad_s[i], block.accel_m_s2[i], block.mag_ut[i]))
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        rc = main(["calibrate", "mag", "--method", "backstepping", str(path), "--lat", str(DEFAULT_SITE.lat_deg),
                   "--lon", str(DEFAULT_SITE.lon_deg), "--alt-m", str(DEFAULT_SITE.alt_m),
                   "--date", DEFAULT_SITE.date.isoformat(), "--state-dir", str(tmp_path / "offline"), "--json"])
    assert rc == 0, out.getvalue()
    res = json.loads(out.getvalue())
    return MagModel(np.array(res["hard_iron_ut"]), np.array(res["soft_iron"]))


@pytest.mark.parametrize("tilt_deg", [2.0, 30.0])
def test_daemon_session_beats_offsets_only_and_matches_the_offline_fit(tmp_path, tilt_deg):
    port = free_udp_port()
    client = Client(port)   # bound before the daemon starts sending
    daemon = start_daemon(tmp_path, port, tilt_deg, straight_runs=False, time_scale=10.0)
    try:
        report, texts = run_session(client)
    finally:
        daemon.stop()
    assert report.cal_status == 4, texts + [(tmp_path / "daemon.log").read_text()[-2000:]]
    saved = CalibrationStore(tmp_path / "state").load()
    meta = saved.metadata["mag"]
    assert meta["method"] == "field:backstepping"
    t0, t1 = meta["data_span_s"]
    assert t1 - t0 < 120.0                    # about 1.5 turns at any tilt
    # the same samples through the offline fit: `ahrsd calibrate mag --method backstepping` on a recording of
    # the stretch the session used
    block = record(vehicle(tilt_deg), RECORDING_S)
    sel = (block.t_s >= t0) & (block.t_s <= t1)
    offline = offline_backstepping(tmp_path, block, sel)
    eul = truth_euler(block)[sel]
    offsets, _ = fit_offsets_keep_soft_iron(block.mag_ut[sel], np.eye(3), np.zeros(3), eul[:, 2], eul[:, 1],
                                            SITE_FIELD)
    iron = injected_iron()
    field = heading_rms_deg(saved.mag, iron, remove_mean=True)
    field_total = heading_rms_deg(saved.mag, iron)
    off_line = heading_rms_deg(offline, iron, remove_mean=True)
    off_only = heading_rms_deg(offsets, iron, remove_mean=True)
    accuracy = next((t for t in texts if t.startswith("Mag cal: heading")), "")
    print(f"\ndaemon ±{tilt_deg:.0f}°: {t1 - t0:.0f} s of data; heading RMS on other attitudes (mean removed) "
          f"field {field:.2f}°, `ahrsd calibrate mag` {off_line:.2f}°, offsets-only {off_only:.2f}°; with the offset field "
          f"{field_total:.2f}°, offline {heading_rms_deg(offline, iron):.2f}°; '{accuracy}'")
    assert accuracy, texts
    assert field < off_only / 3
    # the same within noise: 0.1° (the bound for ±2°), or the fit's predicted 1σ where larger
    tolerance = 0.1 if tilt_deg == 2.0 else max(0.1, meta["heading_std_deg"])
    assert abs(field - off_line) < tolerance
    assert abs(field_total - heading_rms_deg(offline, iron)) < tolerance


def autopilot_gps_raw_int(tmp_path: Path, arrival, valid, course_rad, speed_m_s) -> dict:
    """start_daemon's `autopilot`: fix k (valid at valid[k], course and ground speed) sent as GPS_RAW_INT when
    the replay reaches arrival[k], from system 1 component 1 on its own UDP link; its counters (sent, taken by
    the session, the latest sample time after its arrival at which one was taken, time-outs) in a JSON file."""
    return {"port": free_udp_port(), "arrival_s": [float(t) for t in arrival],
            "valid_usec": [int(round(t * 1e6)) for t in valid],
            "course_cdeg": [int(round(math.degrees(c) * 100)) % 36000 for c in course_rad],
            "speed_cm_s": [int(round(v * 100)) for v in speed_m_s],
            "lat_e7": int(DEFAULT_SITE.lat_deg * 1e7), "lon_e7": int(DEFAULT_SITE.lon_deg * 1e7),
            "alt_mm": int(DEFAULT_SITE.alt_m * 1e3), "stats_file": str(tmp_path / "autopilot.json")}


def test_daemon_session_with_gnss_course_removes_the_offset(tmp_path):
    """The autopilot's GPS_RAW_INT, 5 Hz, course from the truth at the fix's time of validity (0.5° noise),
    arriving 0.1 s later (the daemon is configured with that latency), a 0.18 m/s current: heading RMS on other
    attitudes, offset included, ≤ 0.4°.

    The daemon stamps a fix with the newest sample when it arrives, as it must for a live link. Replayed 10×
    faster than real time, a fix sent by the wall clock would land 10 ms of recording late for every ms of
    load; so the autopilot sends each fix when the replay reaches its arrival time, and while the session runs
    the recording waits there until the daemon has taken it (start_daemon's `autopilot`): each fix reaches the
    daemon at its own arrival in recording time, at any load."""
    sc = vehicle(2.0, straight_runs=True)
    arrival, valid, course, speed = course_fixes(sc, RECORDING_S, current_ne_m_s=(0.1, -0.15))
    port = free_udp_port()
    client = Client(port)
    autopilot = autopilot_gps_raw_int(tmp_path, arrival, valid, course, speed)
    daemon = start_daemon(tmp_path, port, 2.0, straight_runs=True, time_scale=10.0,
                          magcal={"gnss_latency_s": 0.1}, autopilot=autopilot)
    try:
        report, texts = run_session(client, timeout_s=180.0)
    finally:
        daemon.stop()
    daemon_log = (tmp_path / "daemon.log").read_text()
    assert report.cal_status == 4, texts + [daemon_log[-2000:]]
    saved = CalibrationStore(tmp_path / "state").load()
    meta = saved.metadata["mag"]
    total = heading_rms_deg(saved.mag, injected_iron())
    fed = json.loads(Path(autopilot["stats_file"]).read_text())
    print(f"\ndaemon with GPS_RAW_INT course: offset from {meta['offset_source']} ±{meta['offset_std_deg']:.2f}°; "
          f"heading RMS on other attitudes incl. the offset {total:.2f}°; {fed['taken']} fixes taken by the "
          f"session, latest {fed['late_s'] * 1e3:.1f} ms of recording after its arrival, {fed['timeouts']} time-outs")
    # every fix of the session was taken at its arrival (within a sample), none after a time-out
    assert fed["taken"] > 100 and fed["timeouts"] == 0 and fed["late_s"] <= 1.0 / FIELD_RATE_HZ, fed
    assert meta["offset_source"] == "GNSS course", texts
    assert any("GNSS course" in t for t in texts) or meta["offset_source"] == "GNSS course"
    assert total <= 0.4


class _LateTicks:
    """The protocol handler with its tick let through only once every `every_s` of the (stepped) clock: the
    wall-clock tick of a daemon that runs through that much recording between two ticks."""

    def __init__(self, proto, clock, every_s: float):
        self.proto, self.clock, self.every_s, self._next = proto, clock, every_s, -math.inf

    def on_sample(self, sample, est) -> None:
        self.proto.on_sample(sample, est)

    def on_gnss_message(self, msg) -> None:
        self.proto.on_gnss_message(msg)

    @property
    def _fit_future(self):               # what support.magcal_host.tick_settled waits for
        return self.proto._fit_future

    def tick(self) -> None:
        if self.clock() >= self._next:
            self._next = self.clock() + self.every_s
            self.proto.tick()


def _session_data_span(tmp_path, tick_every_s: float) -> tuple[float, float]:
    """A ±10° session through the protocol handler on a stepped clock (clock = sample time, fits in a thread, the
    truth attitude as the estimate: test_magcal_protocol's driver), ticked every `tick_every_s` of sample time;
    the saved calibration's data span."""
    from ahrsd.daemon.magcal import CMD_ACCEPT, CMD_START, MagCalProtocol, MagCalSettings
    from support.magcal_host import Clock, FakeHost, cmd
    from support.magcal_host import drive_vehicle

    host = FakeHost(tmp_path)
    host.reference_field = lambda lat_deg=None, lon_deg=None: SITE_FIELD
    clock = Clock()
    proto = MagCalProtocol(host, MagCalSettings(), clock=clock, warm_fit_worker=False, fit_in_process=False)
    try:
        assert proto.handle_start(cmd(CMD_START)) == mavlink.MAV_RESULT_ACCEPTED
        drive_vehicle(_LateTicks(proto, clock, tick_every_s), clock, record(vehicle(10.0), 150.0), host,
                       until=lambda: bool(host.of_type("MAG_CAL_REPORT")))
        assert host.of_type("MAG_CAL_REPORT")[-1].cal_status == 4, host.texts()
        assert proto.handle_accept(cmd(CMD_ACCEPT)) == mavlink.MAV_RESULT_ACCEPTED
    finally:
        proto.close()
    t0, t1 = CalibrationStore(tmp_path).load().metadata["mag"]["data_span_s"]
    return t0, t1

def test_the_session_data_ends_where_it_asked_for_its_fit_however_late_the_tick(tmp_path):
    """The session asks for its final fit at a sample (coverage, in sample time); the tick that collects fits
    runs on the wall clock (10 Hz). A daemon catching up after a stall on a loaded machine processes tens of
    seconds of recording between two ticks, so the data must end at the request, not at the next tick: the
    same span whether the tick comes every 0.1 s or every 20 s of sample time."""
    prompt = _session_data_span(tmp_path / "prompt", 0.1)
    late = _session_data_span(tmp_path / "late", 20.0)
    print(f"\nsession data span, tick every 0.1 s: {prompt[0]:.2f}-{prompt[1]:.2f} s; every 20 s: "
          f"{late[0]:.2f}-{late[1]:.2f} s")
    assert prompt[1] - prompt[0] < 120.0
    assert late == pytest.approx(prompt, abs=0.051)      # one kept block (20 Hz)
