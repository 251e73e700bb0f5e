"""Every GNSS backend through the same GnssTask loop (daemon.gnss_task), on a stepped clock.

The same six epochs, one of them at an impossible latitude (95° N), reach the task through each source: a
receiver on a serial port speaking UBX and one speaking NMEA (a simulated receiver on a pty: the hardware
path), the autopilot's GPS_RAW_INT, a GNSS recording, and a backend written here in a dozen lines. Each must
come out alike: every fix logged with its verdict, the impossible one rejected by the validator and never
offered to the estimator or the subscribers, the others offered in order, each stamped on the clock the
backend was given (no wall-clock anywhere but the pty's own delivery, waited for with select).
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
import select
import tomllib

import pytest

from ahrsd.core.gnss import GnssFix, make_fix
from ahrsd.daemon.config import GnssConfig, parse_config
from ahrsd.daemon.gnss_task import GnssTask, gnss_backend_for, on_first_fix
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.drivers.gnss.backend import GnssBackend, GnssHealth, GnssLinkState
from ahrsd.drivers.gnss.mavlink import MavlinkGnssBackend
from ahrsd.drivers.gnss.recording import GnssRecordingWriter
from ahrsd.drivers.gnss.replay import RecordingGnssBackend
from ahrsd.drivers.gnss.serial_port import SerialGnssSource
from ahrsd.drivers.gnss.simulated import SimulatedGnssReceiver
from support.fake_aided import GateCounters, WithoutLeverArmCheck

LATENCY_S = 0.1
BAD = 3                                   # the epoch at 95° N
EPOCHS = [make_fix(10.0 + 0.2 * k, 95.0 if k == BAD else 47.0 + 1e-4 * k, 8.0 + 2e-4 * k, 500.0 + k,
                   [3.0, -4.0, 0.0], h_acc_m=1.5, v_acc_m=2.5, s_acc_m_s=0.2, num_sats=9 + k)
          for k in range(6)]
GOOD = [f for k, f in enumerate(EPOCHS) if k != BAD]


class Clock:
    """The stepped clock every backend and the task are given."""

    t = 0.0

    def __call__(self) -> float:
        return self.t


class AidedEstimator(WithoutLeverArmCheck):
    """Records what it is offered (the GnssAidedEstimator protocol of the task)."""

    name = "recorder"

    def __init__(self):
        self.fixes: list[GnssFix] = []
        self.gnss_counters = GateCounters()

    def update_gnss(self, fix: GnssFix) -> int:
        self.fixes.append(fix)
        return 0


@dataclasses.dataclass
class Hook:
    estimator: object
    last_estimate: object = None


@dataclasses.dataclass
class Rig:
    task: GnssTask
    clock: Clock
    estimator: AidedEstimator
    logged: list
    subscribed: list
    first: list
    health: GnssHealth | None = None     # the backend's health at the end of the run, before it was closed

    def finish(self) -> None:
        self.health = self.task.health()
        self.task.close()


def rig_for(backend: GnssBackend, clock: Clock) -> Rig:
    est, logged, subscribed, first = AidedEstimator(), [], [], []
    task = GnssTask(backend, GnssConfig(), clock=clock, estimator=Hook(est), statustext=lambda *a: None,
                    log_fix=lambda fix, rejection: logged.append((fix, rejection)),
                    subscribers=[subscribed.append, on_first_fix(lambda: first.append(clock.t))])
    return Rig(task, clock, est, logged, subscribed, first)


# --------------------------------------------------------------------------------------------- the sources
def run_serial(protocol: str) -> Rig:
    clock = Clock()
    with SimulatedGnssReceiver(protocol=protocol) as rx:
        backend = SerialGnssSource(rx.device, 115200, protocol, latency_s=LATENCY_S, clock=clock)
        rig = rig_for(backend, clock)
        rig.task.open()
        try:
            for fix in EPOCHS:
                clock.t = fix.t_s + LATENCY_S            # the epoch's bytes arrive one latency after it
                rx.write_fix(fix)
                select.select([backend.fileno()], [], [], 5.0)
                rig.task.poll()
        finally:
            rig.finish()
    return rig


def gps_raw_int(fix: GnssFix, time_usec: int):
    vn, ve, _ = fix.vel_ned_m_s
    return mavlink.MAVLink_gps_raw_int_message(
        time_usec, 3, round(fix.lat_deg * 1e7), round(fix.lon_deg * 1e7), round(fix.alt_m * 1000), 90, 150,
        round(math.hypot(vn, ve) * 100), round(math.degrees(math.atan2(ve, vn)) % 360 * 100), fix.num_sats,
        round(fix.alt_m * 1000), round(fix.h_acc_m * 1000), round(fix.v_acc_m * 1000),
        round(fix.s_acc_m_s * 1000), 0)


def run_mavlink() -> Rig:
    clock = Clock()
    rig = rig_for(MavlinkGnssBackend(latency_s=LATENCY_S), clock)
    rig.task.open()
    for k, fix in enumerate(EPOCHS):
        clock.t = fix.t_s + LATENCY_S
        rig.task.on_mavlink(gps_raw_int(fix, 1_000_000 + 200_000 * k), clock.t)
    rig.finish()
    return rig


def run_recording(tmp_path) -> Rig:
    path = tmp_path / "rec.gnss.csv"
    with GnssRecordingWriter(path) as w:
        for fix in EPOCHS:
            w.write(fix)
    clock = Clock()                                   # here: the replayed IMU samples' time
    rig = rig_for(RecordingGnssBackend(path, replay_time_s=clock), clock)
    rig.task.open()
    for fix in EPOCHS:
        clock.t = fix.t_s - 0.01
        assert rig.task.poll() == 0                   # not due before the samples reach its time
        clock.t = fix.t_s
        assert rig.task.poll() == 1
    rig.finish()
    return rig


class ListBackend(GnssBackend):
    """A whole new source: fixes from a list, each due when the clock reaches its time."""

    description = "a list"

    def __init__(self, fixes, clock):
        self.fixes, self.clock, self.delivered = list(fixes), clock, 0

    def read(self) -> list[GnssFix]:
        due = [f for f in self.fixes if f.t_s <= self.clock()]
        self.fixes = self.fixes[len(due):]
        self.delivered += len(due)
        return due

    def health(self) -> GnssHealth:
        return GnssHealth(GnssLinkState.OK if self.delivered else GnssLinkState.WAITING)

    def stats(self) -> dict[str, dict]:
        return {"list": {"delivered": self.delivered}}


def run_list() -> Rig:
    clock = Clock()
    rig = rig_for(ListBackend(EPOCHS, clock), clock)
    rig.task.open()
    for fix in EPOCHS:
        clock.t = fix.t_s
        rig.task.tick(clock.t)                        # no descriptor: housekeeping polls it
    rig.finish()
    return rig


SOURCES = {
    "serial ubx": lambda tmp_path: run_serial("ubx"),
    "serial nmea": lambda tmp_path: run_serial("nmea"),
    "autopilot mavlink": lambda tmp_path: run_mavlink(),
    "recording": run_recording,
    "a new backend": lambda tmp_path: run_list(),
}


@pytest.mark.parametrize("source", SOURCES)
def test_every_backend_goes_through_the_same_validation_and_hand_over(source, tmp_path):
    rig = SOURCES[source](tmp_path)
    c = rig.task.counters
    verdicts = [(round(f.lat_deg, 6), None if r is None else r.value) for f, r in rig.logged]
    # every epoch logged once, with its verdict: the impossible latitude refused at the edge
    assert verdicts == [(round(f.lat_deg, 6), "out_of_range" if k == BAD else None)
                        for k, f in enumerate(EPOCHS)], verdicts
    assert (c.fixes, c.accepted, c.rejected, c.offered, c.source_errors) == (6, 5, 1, 5, 0)
    # the estimator and the subscribers get the good ones, in order, and nothing else
    got = rig.estimator.fixes
    assert [v for f in got for v in (f.lat_deg, f.lon_deg)] == pytest.approx(
        [v for f in GOOD for v in (f.lat_deg, f.lon_deg)], abs=1e-7)
    assert rig.subscribed == got and len(rig.first) == 1
    # time of validity on the clock the backend was given: the epoch's own time, whatever the path
    assert [f.t_s for f in got] == pytest.approx([f.t_s for f in GOOD], abs=1e-9)
    assert rig.task.position == pytest.approx((GOOD[-1].lat_deg, GOOD[-1].lon_deg, GOOD[-1].alt_m), abs=1e-6)
    assert rig.health.state is GnssLinkState.OK, rig.health


def test_the_simulated_receiver_takes_the_serial_path():
    """[gnss] source = "sim": the scenario's receiver writes UBX into a pty and the serial backend reads it;
    its invalid-position glitches are refused by the same validator, the rest reach the estimator."""
    config = parse_config(tomllib.loads('[sensor]\nsource = "sim"\nscenario = "car"\nseed = 3\n'
                                        '[gnss]\nsource = "sim"\nsim_glitch_every_s = 1.0\n'
                                        'sim_glitch_kind = "nan"\n'))
    clock = Clock()
    backend = gnss_backend_for(config.gnss, clock=clock, sensor=config.sensor, scenario_clock=clock,
                              sim_writer_thread=False)     # stepped here: write_due
    assert isinstance(backend.port, SerialGnssSource)
    rig = rig_for(backend, clock)
    rig.task.open()
    rx = backend.receiver
    try:
        for k in range(1, 401):                       # 4 s in 10 ms steps
            clock.t = k * 0.01
            before = rx.fixes_written
            rx.write_due()
            if rx.fixes_written > before:
                select.select([backend.fileno()], [], [], 5.0)
            rig.task.poll()
    finally:
        rig.task.close()
    stats = rig.task.stats()
    written, glitches = stats["sim_receiver"]["fixes_written"], stats["sim_receiver"]["glitches_written"]
    assert written >= 15 and glitches == 3, stats     # 5 Hz for 4 s; glitches at 1, 2 and 3 s
    assert stats["serial"]["frames_ubx"] == written
    refused = [r.value for _, r in rig.logged if r is not None]
    assert refused == ["nonfinite_field"] * glitches
    assert len(rig.estimator.fixes) == written - glitches == rig.task.counters.offered
    assert all(math.isfinite(f.lat_deg) for f in rig.estimator.fixes) and rig.subscribed == rig.estimator.fixes


def test_a_new_backend_is_one_class():
    """The interface is the whole contract: a class missing `read` cannot be built, and the task merges a
    new backend's counters into its stats under the backend's own name."""

    class NoRead(GnssBackend):
        def health(self):
            return GnssHealth(GnssLinkState.OK)

        def stats(self):
            return {}

    with pytest.raises(TypeError, match="read"):
        NoRead()
    rig = run_list()
    assert rig.task.stats()["list"] == {"delivered": 6}
    assert rig.task.description == "a list" and rig.task.status(rig.clock.t) == "GNSS 3D 14 sats, unaided"


def test_a_failing_subscriber_is_counted_and_the_others_still_get_every_fix():
    """A subscriber that raises (one of the daemon's parts failing) neither takes the task down nor starves the
    subscribers after it: each good fix reaches them, and each failure is counted."""
    clock, recorder, after = Clock(), AidedEstimator(), []

    def failing(fix):
        raise RuntimeError("a faulty part")

    task = GnssTask(ListBackend(EPOCHS, clock), GnssConfig(), clock=clock, estimator=Hook(recorder),
                    statustext=lambda *a: None, subscribers=[failing, after.append])
    task.open()
    for fix in EPOCHS:
        clock.t = fix.t_s
        task.tick(clock.t)
    task.close()
    assert after == recorder.fixes and [f.lat_deg for f in after] == [f.lat_deg for f in GOOD]
    assert task.counters.subscriber_errors == len(GOOD)


def test_a_serial_backend_is_read_when_its_descriptor_is_readable():
    """On an event loop, the task watches the backend's descriptor: a fix written to the port is delivered
    without any housekeeping tick."""
    clock = Clock()
    with SimulatedGnssReceiver(protocol="ubx") as rx:
        backend = SerialGnssSource(rx.device, 115200, "ubx", latency_s=0.0, clock=clock)
        rig = rig_for(backend, clock)
        loop = asyncio.new_event_loop()
        try:
            rig.task.open(loop)

            async def until_delivered():
                while not rig.estimator.fixes:
                    await asyncio.sleep(0.01)
            clock.t = GOOD[0].t_s
            rx.write_fix(GOOD[0])
            loop.run_until_complete(asyncio.wait_for(until_delivered(), 30.0))
        finally:
            rig.task.close()
            loop.close()
    assert [f.t_s for f in rig.estimator.fixes] == [GOOD[0].t_s]


def test_a_recording_that_breaks_mid_file_is_a_device_error_not_a_crash(tmp_path):
    path = tmp_path / "rec.gnss.csv"
    with GnssRecordingWriter(path) as w:
        for fix in GOOD[:2]:
            w.write(fix)
    with open(path, "a") as f:
        f.write("11.0,47.0,8.0,not-a-number,0,0,0,1,1,1,3,9,nan\n")
    clock = Clock()
    rig = rig_for(RecordingGnssBackend(path, replay_time_s=clock), clock)
    rig.task.open()
    clock.t = 100.0
    rig.task.tick(clock.t)
    health = rig.task.health()
    assert len(rig.estimator.fixes) == 2 and rig.task.counters.source_errors == 0
    assert health.state is GnssLinkState.DEVICE_ERROR and "line 4" in health.message
    assert rig.task.stats()["recording"] == {"fixes": 2, "errors": 1, "finished": True}
    assert rig.task.fix_summary(clock.t) == "device error"
