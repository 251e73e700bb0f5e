"""The daemon's on-vehicle logs ([log], daemon.vehicle_log): the daemon runs in-process on the simulated chip with
logging on; what it logged is compared with the raw samples its source delivered (captured by a tap on the
source, not through the logging path): `ahrsd log cut` gives exactly those samples, and `replay` and
`calibrate gyro --bias-only` on the cut give what they give on a recording written directly from the tap.
The .tlog reads with pymavlink's mavlink_connection (what mavlogdump.py uses). A full disk and a read-only
directory stop the log with one warning while the daemon keeps reading and sending."""

from __future__ import annotations

import asyncio
import dataclasses
import errno
import json
import logging
import time

import numpy as np
import pytest

from ahrsd.cli.main import main
from ahrsd.daemon.config import Config, ConfigError, EndpointConfig, LogConfig, StateConfig, parse_config
from ahrsd.daemon.mavlink_io import mavlink, mavutil
from ahrsd.daemon.run_stats import collect_stats
from ahrsd.daemon.service import Service
from ahrsd.drivers.recording import SAMPLE_COLUMNS, RecordingWriter, read_recording
from ahrsd.drivers.sample_log import SampleLog
from ahrsd.drivers.source import open_source

from service_rig import gcs_socket

GCS_SYS, GCS_COMP = 255, 190


class TappedSource:
    """The daemon's sensor source, keeping every sample it hands to the reader (the truth for the log)."""

    def __init__(self, source):
        self._source = source
        self.samples = []

    def read_one(self, now):
        sample = self._source.read_one(now)
        if sample is not None:
            self.samples.append(sample)
        return sample

    def poll(self):                       # the chip read in its own thread (drivers.threaded_source)
        samples = self._source.poll()
        self.samples.extend(samples)
        return samples

    # the rest of drivers.source_interface's members, passed on as the source has them
    description = property(lambda self: self._source.description)
    sample_rate_hz = property(lambda self: self._source.sample_rate_hz)
    per_sample = property(lambda self: self._source.per_sample)
    monotonic_offset_s = property(lambda self: self._source.monotonic_offset_s)
    recording_time_base = property(lambda self: self._source.recording_time_base)
    finished = property(lambda self: self._source.finished)
    chip = property(lambda self: self._source.chip)
    ready_fd = property(lambda self: self._source.ready_fd)
    handover_max_s = property(lambda self: self._source.handover_max_s)

    def hand_over_by(self, t):
        self._source.hand_over_by(t)

    def next_read_time(self):
        return self._source.next_read_time()

    def counters(self):
        return self._source.counters()

    def close(self):
        self._source.close()


@dataclasses.dataclass
class Run:
    service: Service
    samples: list
    attitude_times: list        # arrival times (monotonic) of our ATTITUDE messages at the ground station
    gcs_heartbeats_sent: int
    stats: dict


def run_daemon(tmp_path, seconds: float, log_cfg: LogConfig, min_samples: int = 0) -> Run:
    """Run the daemon for `seconds` of wall clock and, on a loaded machine, on until its source has delivered
    `min_samples` (the reader gets fewer samples per second there; the tests count samples, not seconds)."""
    gcs = gcs_socket()
    cfg = dataclasses.replace(Config(), endpoints=(EndpointConfig(f"udpout:127.0.0.1:{gcs.getsockname()[1]}"),),
                              state=StateConfig(str(tmp_path / "state")), log=log_cfg)
    tap = TappedSource(open_source(cfg.sensor, clock=time.monotonic))
    service = Service(cfg, source=tap, environ={})
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    gcs_mav = mavlink.MAVLink(None, srcSystem=GCS_SYS, srcComponent=GCS_COMP)
    attitude_times: list[float] = []
    sent = [0]
    peer = [None]

    def on_gcs_readable():
        while True:
            try:
                data, addr = gcs.recvfrom(65535)
            except BlockingIOError:
                return
            peer[0] = addr
            for m in parser.parse_buffer(data) or ():
                if m.get_type() == "ATTITUDE":
                    attitude_times.append(time.monotonic())

    async def ground_station():
        while True:
            await asyncio.sleep(0.5)
            if peer[0] is not None:   # a GCS heartbeat back to the daemon: inbound traffic for the tlog
                hb = gcs_mav.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                gcs.sendto(hb.pack(gcs_mav), peer[0])
                sent[0] += 1

    async def go():
        loop = asyncio.get_running_loop()
        loop.add_reader(gcs.fileno(), on_gcs_readable)
        gs = loop.create_task(ground_station())
        async def stop_when_enough():
            t_end, t_give_up = time.monotonic() + seconds, time.monotonic() + seconds + 600.0
            while time.monotonic() < t_give_up and (time.monotonic() < t_end or len(tap.samples) < min_samples):
                await asyncio.sleep(0.1)
            service.request_stop(0)

        stopper = loop.create_task(stop_when_enough())
        code = await service.run()
        stopper.cancel()
        gs.cancel()
        loop.remove_reader(gcs.fileno())
        return code

    try:
        assert asyncio.run(go()) == 0
    finally:
        gcs.close()
    return Run(service, tap.samples, attitude_times, sent[0], collect_stats(service))


def cli(*argv):
    return main([str(a) for a in argv])


@pytest.fixture(scope="module")
def logged_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("vehicle_log")
    return tmp, run_daemon(tmp, 8.0, LogConfig(enabled=True, rotate_mb=0.05), min_samples=4100)


def test_the_cut_is_exactly_the_samples_the_daemon_read(logged_run, capsys):
    tmp, run = logged_run
    logs = run.stats["logs"]
    assert logs["samples"]["written"] == len(run.samples) > 4000    # 8 s at 819.2 SPS, less start-up
    assert logs["samples"]["dropped"] == 0 and logs["samples"]["failure"] is None
    assert logs["samples"]["files_opened"] >= 2                       # rotated at 0.05 MB
    t0, t1 = run.samples[0].t_s, run.samples[-1].t_s
    cut = tmp / "cut.csv.gz"
    assert cli("log", "cut", "--dir", tmp / "state" / "logs", "--from", t0 - 1, "--to", t1 + 1, "--output", cut,
               "--quiet") == 0
    rec = read_recording(cut)
    assert len(rec.t_s) == len(run.samples)
    np.testing.assert_array_equal(rec.t_s, [s.t_s for s in run.samples])
    np.testing.assert_array_equal(rec.gyro_rad_s, np.array([s.gyro_rad_s for s in run.samples]))
    np.testing.assert_array_equal(rec.accel_m_s2, np.array([s.accel_m_s2 for s in run.samples]))
    np.testing.assert_array_equal(rec.mag_ut, np.array([s.mag_ut for s in run.samples]))

    direct = tmp / "direct.csv"
    with RecordingWriter(direct, extra_columns=SAMPLE_COLUMNS) as w:
        for s in run.samples:
            w.write(s)
    fits = []
    for path in (cut, direct):
        capsys.readouterr()
        assert cli("calibrate", "gyro", path, "--bias-only", "--json", "--dry-run", "--state-dir", tmp / "cal") == 0
        fit = json.loads(capsys.readouterr().out)
        assert fit.pop("source").endswith(path.name)   # the only difference: the file it read
        fits.append(fit)
    assert fits[0] == fits[1] and fits[0]["bias_rad_s"]
    assert cli("replay", cut, "--output", tmp / "att_cut.csv", "--quiet") == 0
    assert cli("replay", direct, "--output", tmp / "att_direct.csv", "--quiet") == 0
    assert (tmp / "att_cut.csv").read_text() == (tmp / "att_direct.csv").read_text()


def test_the_tlog_holds_every_frame_out_and_in(logged_run):
    tmp, run = logged_run
    tlogs = sorted((tmp / "state" / "logs").glob("mavlink-*.tlog"))
    assert tlogs
    ours, theirs = {}, 0
    for path in tlogs:
        conn = mavutil.mavlink_connection(str(path), dialect="ardupilotmega")
        while (m := conn.recv_match()) is not None:
            if m.get_srcSystem() == GCS_SYS and m.get_srcComponent() == GCS_COMP:
                theirs += m.get_type() == "HEARTBEAT"
            elif m.get_srcComponent() == run.service.component_id:
                ours[m.get_type()] = ours.get(m.get_type(), 0) + 1
    link = next(iter(run.stats["links"].values()))
    assert sum(ours.values()) == link["tx_messages"]      # every frame sent, once
    assert ours["ATTITUDE"] == len(run.attitude_times) > 100 and ours["HEARTBEAT"] >= 5
    assert theirs == link["rx_messages"] >= 5 and theirs <= run.gcs_heartbeats_sent


def test_a_calibration_swap_starts_a_file_naming_the_new_calibration(tmp_path):
    from ahrsd.calibration.models import Calibration, GyroModel

    cfg = dataclasses.replace(Config(), endpoints=(EndpointConfig("udpout:127.0.0.1:9"),),
                              state=StateConfig(str(tmp_path / "state")), log=LogConfig(enabled=True, tlog=False))
    service = Service(cfg, source=TappedSource(open_source(cfg.sensor, clock=time.monotonic)), environ={})

    logs = tmp_path / "state" / "logs"

    async def until(done, what):
        # conditions, not wall-clock times: on a loaded machine the daemon's start alone can take longer than a
        # fixed delay, and a swap before the first file opened left one file (seen at load 4.5, 2026-12-07)
        for _ in range(1200):
            if done():
                return
            await asyncio.sleep(0.05)
        raise AssertionError(f"60 s without {what}")

    async def go():
        cal = Calibration().with_sensor("gyro", GyroModel(np.array([1e-3, 0.0, 0.0]), np.eye(3)), method="test-bias")
        run = asyncio.ensure_future(service.run())
        await until(lambda: run.done() or len(service.source.samples) >= 800 and any(logs.glob("imu-*.csv.gz.json")),
                    "the first log file")
        service.apply_calibration(cal)
        swapped_at = len(service.source.samples)
        await until(lambda: run.done() or len(service.source.samples) >= swapped_at + 800, "samples after the swap")
        service.request_stop(0)
        return await run, cal
    code, cal = asyncio.run(go())
    assert code == 0
    sidecars = sorted((tmp_path / "state" / "logs").glob("imu-*.csv.gz.json"))
    cals = [json.loads(p.read_text())["calibration"] for p in sidecars]
    assert len(cals) == 2 and cals[0]["identity"] and not cals[1]["identity"]
    from ahrsd.calibration.store import checksum
    assert cals[1]["checksum"] == checksum(cal.to_dict()) and "gyro:test-bias" in cals[1]["method"]
    # raw samples: a window across the swap is still one recording
    assert main(["log", "cut", "--dir", str(tmp_path / "state" / "logs"), "--from", "0", "--to", "1e9",
                 "--output", str(tmp_path / "all.csv"), "--quiet"]) == 0
    assert len(read_recording(tmp_path / "all.csv").t_s) == len(service.source.samples)


def failing_write(err):
    """SampleLog._write_block that fails like the disk would once 1000 samples are in."""
    original = SampleLog._write_block

    def write(self, file, block):
        if self.written + len(block) > 1000:
            raise OSError(err, __import__("os").strerror(err))
        original(self, file, block)
    return write


@pytest.mark.parametrize("err", [errno.ENOSPC, errno.EROFS])
def test_a_full_or_read_only_disk_stops_the_log_and_the_daemon_carries_on(tmp_path, monkeypatch, caplog, err):
    monkeypatch.setattr(SampleLog, "_write_block", failing_write(err))
    with caplog.at_level(logging.WARNING, logger="ahrsd.drivers.rotating_log"):
        run = run_daemon(tmp_path, 5.0, LogConfig(enabled=True), min_samples=2600)
    s = run.stats["logs"]["samples"]
    assert s["failure"] == __import__("os").strerror(err) and 500 < s["written"] <= 1000
    assert s["written"] + s["dropped"] == len(run.samples)   # every sample the reader saw is accounted for
    assert len([r for r in caplog.records if "stopped" in r.getMessage()]) == 1
    # the daemon kept reading and sending after the failure (1000 samples ≈ 1.2 s into the run)
    assert len(run.samples) > 2500
    late = [t for t in run.attitude_times if t > run.attitude_times[0] + 2.5]
    assert len(late) > 50                                    # ATTITUDE (50 Hz) still flowing
    assert run.stats["logs"]["tlog"]["failure"] is None       # the other log is unaffected


def test_a_directory_that_cannot_be_created_stops_the_logs_with_one_warning_each(tmp_path, caplog):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory")
    with caplog.at_level(logging.WARNING, logger="ahrsd.drivers.rotating_log"):
        run = run_daemon(tmp_path, 3.0, LogConfig(enabled=True, dir=str(blocker / "logs")))
    logs = run.stats["logs"]
    assert logs["samples"]["failure"] and logs["samples"]["written"] == 0
    assert logs["samples"]["dropped"] == len(run.samples) > 1000
    assert logs["tlog"]["failure"] and len([r for r in caplog.records if "stopped" in r.getMessage()]) == 2


def test_log_config_defaults_validation_and_systemd_default(tmp_path):
    assert not LogConfig().is_enabled({}) and LogConfig().is_enabled({"INVOCATION_ID": "x"})
    assert LogConfig().is_enabled({"NOTIFY_SOCKET": "/run/systemd/notify"})
    assert not LogConfig(enabled=False).is_enabled({"INVOCATION_ID": "x"})
    assert LogConfig().resolve_dir(tmp_path) == tmp_path / "logs"
    cfg = parse_config({"log": {"enabled": True, "dir": "/x", "max_total_mb": 10, "rotate_mb": 1, "rotate_s": 60,
                                "samples": False, "tlog": True}})
    assert cfg.log == LogConfig(True, "/x", 10.0, 1.0, 60.0, False, True)
    for bad, key in (({"enabled": "yes"}, "log.enabled"), ({"max_total_mb": 0}, "log.max_total_mb"),
                     ({"rotate_mb": 20, "max_total_mb": 10}, "log.rotate_mb"), ({"sample": True}, "log.sample")):
        with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
            parse_config({"log": bad})
    over = Config().with_overrides(log_dir="/l")
    assert over.log.enabled and over.log.dir == "/l"
    assert Config().with_overrides(log_enabled=False).log.enabled is False


def test_logging_off_writes_nothing(tmp_path):
    run = run_daemon(tmp_path, 1.5, LogConfig())   # not under systemd: off by default
    assert run.stats["logs"] == {} and not (tmp_path / "state" / "logs").exists()
