"""The daemon's GNSS input (daemon.gnss_task): a fake autopilot's GPS_RAW_INT over UDP reaches the aided
estimator, hostile values are rejected and counted at the edge, SYS_STATUS carries the GPS bit, STATUSTEXT
reports the GNSS state, and the navigation outputs are built from the aided estimator's state."""

from __future__ import annotations

import asyncio
import dataclasses
import math
import time

import numpy as np
import pytest

from ahrsd.core.estimate import EstimateFlags
from ahrsd.core.sample import make_sample
from ahrsd.daemon.config import Config, EstimatorConfig, GnssConfig, OutputsConfig
from ahrsd.daemon.mavlink_io import mavlink
from service_rig import gcs_socket, start_service, stop_service
from support.fake_aided import FakeAided
from support.mavlink_feed import drain

GPS = mavlink.MAV_SYS_STATUS_SENSOR_GPS
AP_SYS, AP_COMP = 1, 1


class Autopilot:
    """A fake autopilot: pymavlink-encoded packets sent over UDP to the daemon's endpoint."""

    def __init__(self, rig):
        self.rig = rig
        self.mav = mavlink.MAVLink(None, srcSystem=AP_SYS, srcComponent=AP_COMP)
        self.time_usec = 1_000_000

    def send(self, msg, sysid=AP_SYS):
        self.mav.srcSystem = sysid
        self.rig.gcs.sendto(bytes(msg.pack(self.mav)), self.rig.daemon_addr)

    def heartbeat(self):
        self.send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_SURFACE_BOAT,
                                                    mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3))

    def gps_raw_int(self, lat=473977418, lon=85455939, alt=488000, vel=500, cog=9000, fix_type=3, sats=11,
                    h_acc=1200, sysid=AP_SYS):
        self.time_usec += 200_000
        self.send(mavlink.MAVLink_gps_raw_int_message(self.time_usec, fix_type, lat, lon, alt, 90, 150, vel, cog,
                                                      sats, 0, h_acc, 2500, 300, 0), sysid)


def pump(rig, seconds=0.05):
    rig.loop.run_until_complete(asyncio.sleep(seconds))


def received(rig) -> list:
    """Every message the daemon sent to the ground-station socket so far."""
    return drain(rig)


@pytest.fixture
def rig(tmp_path):
    gcs = gcs_socket()
    service, loop = start_service(gcs, tmp_path / "state", gnss=GnssConfig(source="mavlink"))
    r = type("Rig", (), {})()
    r.service, r.loop, r.gcs = service, loop, gcs
    loop.run_until_complete(asyncio.sleep(0.05))
    _, r.daemon_addr = gcs.recvfrom(65536)         # the daemon's first heartbeat says where it listens
    r.fake = service.pipeline.estimator = FakeAided()
    r.ap = Autopilot(r)
    r.ap.heartbeat()
    pump(r)
    yield r
    stop_service(service, loop)
    gcs.close()


def test_gps_raw_int_reaches_the_aided_estimator(rig):
    for _ in range(3):
        rig.ap.gps_raw_int()
    pump(rig)
    fixes = rig.fake.fixes
    assert len(fixes) == 3
    f = fixes[-1]
    # common.xml: degE7, mm, cm/s ground speed with course in cdeg (9000 = east), h_acc mm
    assert (f.lat_deg, f.lon_deg, f.alt_m) == pytest.approx((47.3977418, 8.5455939, 488.0))
    assert f.vel_ned_m_s[:2] == pytest.approx([0.0, 5.0], abs=1e-9) and f.h_acc_m == pytest.approx(1.2)
    assert f.num_sats == 11
    # time of validity: arrival on the monotonic clock (the IMU samples' clock) minus the configured latency
    assert time.monotonic() - 2.0 < f.t_s < time.monotonic() - rig.service.config.gnss.latency_s
    g = rig.service.gnss
    assert (g.counters.accepted, g.counters.offered, g.counters.rejected) == (3, 3, 0)


@pytest.mark.parametrize("hostile, reason", [
    ({"lat": 950_000_000}, "out_of_range"),          # 95° latitude
    ({"lon": -1_900_000_000}, "out_of_range"),       # -190° longitude
    ({"alt": 100_000_000}, "out_of_range"),          # 100 km
    ({"vel": 65_000}, "out_of_range"),               # 650 m/s
    ({"fix_type": 1}, "no_fix"),
    ({"fix_type": 0, "lat": 0, "lon": 0}, "no_fix"),
])
def test_hostile_gps_raw_int_is_rejected_and_counted(rig, hostile, reason):
    rig.ap.gps_raw_int()
    rig.ap.gps_raw_int(**hostile)
    rig.ap.gps_raw_int()
    pump(rig)
    g = rig.service.gnss
    assert len(rig.fake.fixes) == 2                                 # the hostile one never reached it
    assert g.counters.rejected == 1 and g.validator.counters[reason] == 1
    assert all(abs(f.lat_deg) <= 90 and f.fix_type >= 2 for f in rig.fake.fixes)


def test_only_the_autopilot_is_listened_to_and_repeats_are_dropped(rig):
    rig.ap.gps_raw_int()
    rig.ap.gps_raw_int(sysid=7)                     # another system's receiver
    rig.ap.time_usec = 1_000_000
    rig.ap.gps_raw_int()                            # the first fix again (ArduPilot streams it at SRx_EXT_STAT)
    rig.ap.send(mavlink.MAVLink_global_position_int_message(5000, 473977418, 85455939, 488000, 0, 100, 0, 0, 0))
    pump(rig)
    assert len(rig.fake.fixes) == 1
    sel = rig.service.gnss.stats()["mavlink"]
    assert sel["gps_raw_int_repeated"] == 1 and sel["global_position_int_skipped"] == 1


def test_sys_status_gps_bit_and_statustext(rig):
    svc = rig.service
    now = time.monotonic()
    status = svc.sys_status_message(now)
    assert status.onboard_control_sensors_present & GPS and status.onboard_control_sensors_enabled & GPS
    assert not status.onboard_control_sensors_health & GPS          # no fix yet
    rig.ap.gps_raw_int()
    pump(rig)
    now = time.monotonic()
    assert svc.sys_status_message(now).onboard_control_sensors_health & GPS
    # stale: no accepted fix for longer than FIX_STALE_S
    assert not svc.sys_status_message(now + 3.0).onboard_control_sensors_health & GPS
    received(rig)
    svc.gnss.tick(now)
    texts = [m.text for m in received(rig) if m.get_type() == "STATUSTEXT"]
    assert texts == ["ahrsd: GNSS 3D 11 sats, unaided"]
    rig.fake.flags = EstimateFlags.GNSS_AIDED
    process(svc, rig.loop, 1.0, 1)
    svc.gnss.tick(now + 1.0)                                         # changed, but within the rate limit
    assert not [m for m in received(rig) if m.get_type() == "STATUSTEXT"]
    svc.gnss.tick(now + 6.0)
    texts = [m.text for m in received(rig) if m.get_type() == "STATUSTEXT"]
    assert texts == ["ahrsd: GNSS no fix, aided"]                    # (its last fix is 6 s old by then)
    assert svc.gnss.status(now) == "GNSS 3D 11 sats, aided"


def test_a_gate_that_rejects_most_velocities_warns_the_operator(rig):
    """Over each 30 s window the daemon looks at what the estimator's innovation gate did; when it rejected
    most of the offered velocities (an antenna not where lever_arm_m says, rolling with the vehicle) the ground
    station gets a warning, once per window, and the counter says so."""
    from types import SimpleNamespace

    from ahrsd.daemon.gnss_task import GATE_WINDOW_S
    from ahrsd.estimator.lever_arm_fit import LeverArmFitResult

    svc = rig.service
    rig.fake.gnss_counters = counters = SimpleNamespace(offered=0, rejected_velocity=0)
    now = time.monotonic()
    svc.gnss.tick(now)
    received(rig)
    counters.offered, counters.rejected_velocity = 150, 10        # a healthy window: nothing said
    svc.gnss.tick(now + GATE_WINDOW_S + 0.1)
    assert not [m for m in received(rig) if m.get_type() == "STATUSTEXT" and "rejected" in m.text]
    counters.offered, counters.rejected_velocity = 300, 100        # 90 of the next 150
    svc.gnss.tick(now + 2 * GATE_WINDOW_S + 0.2)
    texts = [m.text for m in received(rig) if m.get_type() == "STATUSTEXT" and "rejected" in m.text]
    assert texts == ["ahrsd: GNSS vel rejected 90/150: lever arm?"] and len(texts[0]) <= 50
    assert svc.gnss.counters.gate_warnings == 1
    svc.gnss.tick(now + 2 * GATE_WINDOW_S + 5.0)                   # within the window: not repeated
    assert not [m for m in received(rig) if m.get_type() == "STATUSTEXT" and "rejected" in m.text]
    # the lever-arm check (estimator/lever_arm_fit.py) found where the innovations put the antenna: said instead.
    # Its latch is read (the heading reads it too), not the momentary fit: this window's fit explains less (a calm
    # spell), the arm in use is still found wrong
    fit = LeverArmFitResult(np.array([-1.0, 0.0, -2.0]), np.full(3, 0.2), 0.05, False, arm_wrong=True,
                            heading_bent=True)
    rig.fake.lever_arm_fit = lambda: fit
    counters.offered, counters.rejected_velocity = 450, 190        # 90 of the next 150
    svc.gnss.tick(now + 3 * GATE_WINDOW_S + 0.3)
    texts = [m.text for m in received(rig) if m.get_type() == "STATUSTEXT" and "rej" in m.text]
    assert texts == ["ahrsd: GNSS vel rej 90/150: arm -1.0,0.0,-2.0?"] and len(texts[0]) <= 50
    # a momentary fit that explains them while the latch is off (an adopted arm shown right) leaves the plain hint
    rig.fake.lever_arm_fit = lambda: fit._replace(explains=True, arm_wrong=False, heading_bent=False)
    counters.offered, counters.rejected_velocity = 600, 280
    svc.gnss.tick(now + 4 * GATE_WINDOW_S + 0.4)
    texts = [m.text for m in received(rig) if m.get_type() == "STATUSTEXT" and "rej" in m.text]
    assert texts == ["ahrsd: GNSS vel rejected 90/150: lever arm?"]


def test_the_daemon_says_the_fitted_antenna_arm_it_uses(rig, caplog):
    """Once the aided filter adopts the arm its lever-arm check fitted (estimator/lever_arm_fit.py), the ground
    station is told which arm it uses and that the configuration still holds the told one: once per arm (to 0.1 m),
    not before an adoption. The adopted correction is read (`lever_arm_adopted_m`), not the fit: the tick makes none."""
    svc = rig.service
    now = time.monotonic()
    adopted: list = [None]
    rig.fake.lever_arm_adopted_m = lambda: adopted[0]
    rig.fake.lever_arm_fit = lambda: pytest.fail("the housekeeping tick made a lever-arm fit")
    svc.gnss.tick(now)
    received(rig)
    svc.gnss.tick(now + 0.1)                                         # not adopted: nothing yet
    assert not [m for m in received(rig) if m.get_type() == "STATUSTEXT" and "fitted" in m.text]
    adopted[0] = np.array([-0.93, 0.02, -1.74])
    svc.gnss.tick(now + 0.2)
    svc.gnss.tick(now + 0.3)
    texts = [m.text for m in received(rig) if m.get_type() == "STATUSTEXT" and "fitted" in m.text]
    assert texts == ["ahrsd: GNSS arm -0.9,0.0,-1.7 m fitted: set it"] and len(texts[0]) <= 50
    adopted[0] = np.array([-0.94, 0.01, -1.71])                      # the same arm to 0.1 m: not said again
    svc.gnss.tick(now + 0.35)
    assert not [m for m in received(rig) if m.get_type() == "STATUSTEXT" and "fitted" in m.text]
    adopted[0] = np.array([-1.0, 0.0, -2.0])
    svc.gnss.tick(now + 0.4)
    texts = [m.text for m in received(rig) if m.get_type() == "STATUSTEXT" and "fitted" in m.text]
    assert texts == ["ahrsd: GNSS arm -1.0,0.0,-2.0 m fitted: set it"]
    assert "GNSS arm -1.0,0.0,-2.0 m fitted: set gnss.lever_arm_m" in caplog.text


def test_no_gnss_source_no_gps_bit(tmp_path):
    gcs = gcs_socket()
    service, loop = start_service(gcs, tmp_path / "state")
    try:
        status = service.sys_status_message(time.monotonic())
        assert not status.onboard_control_sensors_present & GPS and service.gnss is None
    finally:
        stop_service(service, loop)
        gcs.close()


def test_navigation_outputs(tmp_path):
    gcs = gcs_socket()
    outputs = dataclasses.replace(OutputsConfig(), local_position_ned_hz=5.0, global_position_int_hz=5.0)
    service, loop = start_service(gcs, tmp_path / "state", gnss=GnssConfig(source="mavlink"), outputs=outputs)
    try:
        fake = service.pipeline.estimator = FakeAided()
        lpn, gpi = mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT
        process(service, loop, 1.0, 1)
        assert service.build_output(lpn, time.monotonic()) is None      # no navigation state yet
        from ahrsd.core.gnss import make_fix

        fake.update_gnss(make_fix(0.9, 47.0, 8.0, 500.0, [0, 0, 0]))
        process(service, loop, 1.1, 2)
        m = service.build_output(lpn, time.monotonic())
        assert (m.x, m.y, m.z) == pytest.approx((0.0, 0.0, 0.0)) and (m.vx, m.vy, m.vz) == pytest.approx(
            (1.5, -2.0, 0.25))
        # 0.001° of latitude north and of longitude east of the origin, 10 m higher: WGS-84 at 47° N
        # (meridian arc 111 180 m/°, parallel 76 020 m/° at 47°; from the ellipsoid's radii of curvature)
        fake.update_gnss(make_fix(1.0, 47.001, 8.001, 510.0, [0, 0, 0]))
        process(service, loop, 1.2, 3)
        m = service.build_output(lpn, time.monotonic())
        a, e2, lat = 6378137.0, 6.69437999014e-3, math.radians(47.0)
        r_n = a * (1 - e2) / (1 - e2 * math.sin(lat) ** 2) ** 1.5
        r_e = a / math.sqrt(1 - e2 * math.sin(lat) ** 2)
        assert m.x == pytest.approx(math.radians(0.001) * r_n, abs=0.05)
        assert m.y == pytest.approx(math.radians(0.001) * r_e * math.cos(lat), abs=0.05)
        assert m.z == pytest.approx(-10.0, abs=0.01)
        g = service.build_output(gpi, time.monotonic())
        assert (g.lat, g.lon, g.alt, g.relative_alt) == (470010000, 80010000, 510000, 10000)
        assert (g.vx, g.vy, g.vz) == (150, -200, 25)
        for ep in service.endpoints:      # gcs profile (the default): the configured rates on every endpoint
            assert ep.schedule.rate_hz(lpn) == 5.0 and ep.schedule.rate_hz(gpi) == 5.0
    finally:
        stop_service(service, loop)
        gcs.close()


def test_the_configured_antenna_lever_arm_reaches_the_aided_estimator(tmp_path):
    """[gnss] lever_arm_m reaches the aided filter as well as the simulated receiver; mekf takes none."""
    gcs = gcs_socket()
    arm = (0.5, -0.25, -1.5)
    service, loop = start_service(gcs, tmp_path / "state", gnss=GnssConfig(source="mavlink", lever_arm_m=arm))
    try:
        assert tuple(service.pipeline.estimator.params.lever_arm_m) == arm
    finally:
        stop_service(service, loop)
    cfg = dataclasses.replace(Config(), gnss=GnssConfig(source="mavlink", lever_arm_m=arm),
                              estimator=EstimatorConfig(name="mekf"))
    assert cfg.estimator_options == {}
    gcs.close()


def test_navigation_outputs_are_off_by_default():
    cfg = OutputsConfig()
    assert cfg.local_position_ned_hz == 0.0 and cfg.global_position_int_hz == 0.0


def process(service, loop, t_s, counter):
    """One sample through the service's hot path, inside its event loop (as the reader runs it)."""
    async def step():
        service.reader.process([make_sample(t_s, [0, 0, 0], [0, 0, -9.8], [20, 0, 40], counter=counter)],
                         time.monotonic())
    loop.run_until_complete(step())


def test_a_receiver_missing_at_start_is_opened_when_it_appears(tmp_path):
    """The IMU does not wait for the GNSS: the daemon starts, reports the device error, and opens the port
    once it exists (the serial backend re-tries every REOPEN_INTERVAL_S when housekeeping polls it); its fixes then flow."""
    from ahrsd.core.gnss import make_fix
    from ahrsd.drivers.gnss.backend import GnssLinkState
    from ahrsd.drivers.gnss.simulated import SimulatedGnssReceiver

    port = tmp_path / "ttyGNSS"                  # a path that appears later (like a USB receiver plugged in)
    gcs = gcs_socket()
    service, loop = start_service(gcs, tmp_path / "state",
                                  gnss=GnssConfig(source="serial", device=str(port), latency_s=0.1))
    rx = SimulatedGnssReceiver(protocol="ubx")
    try:
        g = service.gnss
        fake = service.pipeline.estimator = FakeAided()
        now = time.monotonic()
        assert g.health().state is GnssLinkState.DEVICE_ERROR and g.fix_summary(now) == "device error"
        assert not service.sys_status_message(now).onboard_control_sensors_health & GPS
        port.symlink_to(rx.device)
        deadline = time.monotonic() + 30.0          # the backend re-tries every 2 s when housekeeping polls it
        while g.health().state is GnssLinkState.DEVICE_ERROR and time.monotonic() < deadline:
            g.tick(time.monotonic())
            pump(rig_of(service, loop, gcs), 0.1)
        assert g.health().state is GnssLinkState.WAITING and g.backend.fileno() >= 0
        for k in range(3):
            rx.write_fix(make_fix(100.0 + k, 47.0, 8.0, 500.0, [1.0, 0.0, 0.0], num_sats=10, h_acc_m=1.0,
                                  v_acc_m=2.0, s_acc_m_s=0.1))
            pump(rig_of(service, loop, gcs), 0.1)
        assert len(fake.fixes) == 3 and g.fix_summary(time.monotonic()) == "3D 10 sats", g.stats()
        assert service.sys_status_message(time.monotonic()).onboard_control_sensors_health & GPS
    finally:
        rx.close()
        stop_service(service, loop)
        gcs.close()


def rig_of(service, loop, gcs):
    r = type("Rig", (), {})()
    r.service, r.loop, r.gcs = service, loop, gcs
    return r
