"""The daemon's parts built alone, with fakes or the real small objects they are given (docs/architecture.md):
the position priority shared by the declination and the field calibration, inbound routing, the sample
reader's listeners, the autopilot's GNSS subscription, the health report's heartbeat on a stepped clock."""

from __future__ import annotations

import dataclasses
import math

import pytest

from ahrsd.calibration import Calibration
from ahrsd.core.estimate import EstimateFlags
from ahrsd.core.sample import make_sample
from ahrsd.core.wmm import earth_field
from ahrsd.daemon.autopilot import AutopilotState
from ahrsd.daemon.commands import CommandRouter
from ahrsd.daemon.config import Config, LocationConfig
from ahrsd.daemon.counters import ServiceCounters
from ahrsd.daemon.declination import Declination
from ahrsd.daemon.health import Health
from ahrsd.daemon.heading_resets import HeadingResets
from ahrsd.daemon.heading_slew import HeadingSlew
from ahrsd.daemon.housekeeping import HealthReport
from ahrsd.daemon.inbound import InboundDispatch
from ahrsd.daemon.magcal import DaemonMagCalHost
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.outbound import Identity, Outbound
from ahrsd.daemon.param_protocol import ParamProtocol, param_specs
from ahrsd.daemon.params import ParamStore
from ahrsd.daemon.pipeline import Pipeline
from ahrsd.daemon.position import PositionResolver
from ahrsd.daemon.sample_reader import ReaderOutputs, SampleListeners, SampleReader
from ahrsd.drivers.source_interface import LiveSource
from ahrsd.simulation import DEFAULT_SITE
from support.kept_link import KeptLink
from support.mavlink_feed import as_if_from

# four places with clearly different declinations (each far from the others' by several degrees)
CONFIG_SITE = (64.0, -22.0, 0.0)        # Iceland
GNSS_SITE = (61.2, -149.9, 30.0)        # Alaska
AUTOPILOT_SITE = (-45.0, 170.0, 10.0)   # New Zealand
REMEMBERED_SITE = (-33.9, 18.4, 20.0)   # Cape Town
SIM_SITE = (DEFAULT_SITE.lat_deg, DEFAULT_SITE.lon_deg, DEFAULT_SITE.alt_m)


class Sources:
    """Every position source at once, each removable; `memory` (daemon.position_memory) for a remembered one."""

    def __init__(self, memory=None):
        self.location = LocationConfig(lat_deg=CONFIG_SITE[0], lon_deg=CONFIG_SITE[1], alt_m=CONFIG_SITE[2])
        self.gnss = GNSS_SITE
        self.autopilot = AutopilotState()
        self.autopilot.lat_deg, self.autopilot.lon_deg, self.autopilot.alt_m = AUTOPILOT_SITE
        self.resolver = PositionResolver(self.location, gnss_position=lambda: self.gnss, autopilot=self.autopilot,
                                         simulator=True, memory=memory)

    def drop(self, which: str) -> None:
        if which == "config":
            self.resolver.location = dataclasses.replace(self.location, lat_deg=None, lon_deg=None)
        elif which == "gnss":
            self.gnss = None
        elif which == "autopilot":
            self.autopilot.lat_deg = self.autopilot.lon_deg = None
        elif which == "remembered":
            self.resolver.memory = None
        elif which == "simulator":
            self.resolver.simulator = False


def _declinations_are_distinct():
    d = [earth_field(*p).declination_rad
         for p in (CONFIG_SITE, GNSS_SITE, AUTOPILOT_SITE, REMEMBERED_SITE, SIM_SITE)]
    return min(abs(a - b) for i, a in enumerate(d) for b in d[i + 1:]) > math.radians(3.0)


def _remembered(tmp_path, site, *, record: bool):
    """A memory whose file (written here in the documented format) holds `site`, saved a day ago."""
    import json
    import time

    from ahrsd.daemon.position_memory import FILE_NAME, PositionMemory

    now = time.time()
    (tmp_path / FILE_NAME).write_text(json.dumps({
        "format": "ahrsd-last-position", "schema_version": 1, "lat_deg": site[0], "lon_deg": site[1],
        "alt_m": site[2], "source": "gnss", "wall_time_s": now - 86400.0}))
    return PositionMemory(tmp_path, record=record, wall_clock=lambda: now)


def test_one_position_priority_for_the_declination_and_the_field_calibration(tmp_path):
    """Config > GNSS receiver > autopilot > remembered > simulator site, for both users of a position; every
    source set, then removed one by one in that order (a memory that records nothing: a simulator run)."""
    assert _declinations_are_distinct()
    src = Sources(_remembered(tmp_path, REMEMBERED_SITE, record=False))
    params = ParamStore(param_specs(Config()))
    decl = Declination(params, src.resolver, signal_reset=lambda: None)
    host = DaemonMagCalHost(pipeline=None, swap=None, outbound=None, autopilot=src.autopilot,
                            positions=src.resolver, slew=HeadingSlew())
    expected = [("config", CONFIG_SITE), ("gnss", GNSS_SITE), ("autopilot", AUTOPILOT_SITE),
                ("remembered", REMEMBERED_SITE), ("simulator", SIM_SITE)]
    host.statustext = lambda severity, text: None     # the remembered position is said (tested below)
    for source, site in expected:
        position = src.resolver.position()
        assert position.source == source
        assert (position.lat_deg, position.lon_deg, position.alt_m) == pytest.approx(site)
        truth = earth_field(*site, DEFAULT_SITE.date if source == "simulator" else None)
        decl.resolve()
        assert decl.rad == pytest.approx(truth.declination_rad, abs=1e-12), source
        field = host.reference_field()
        assert field.declination_rad == pytest.approx(truth.declination_rad, abs=1e-12), source
        assert field.ned_ut == pytest.approx(truth.ned_ut), source
        src.drop(source)
    assert src.resolver.position() is None and host.reference_field() is None
    decl.resolve()
    assert decl.rad == 0.0 and decl.waiting_for_position


def test_within_a_run_the_remembered_position_is_the_last_live_one(tmp_path):
    """A daemon on the real chip notes every live position as it arrives: once the receiver and the autopilot are
    gone, the remembered position is the autopilot's last (below them, above the simulator's site), not the
    file's."""
    src = Sources(_remembered(tmp_path, REMEMBERED_SITE, record=True))
    src.drop("config")
    src.resolver.note_live_position()                   # a fix arrives
    assert src.resolver.position().source == "gnss"
    src.drop("gnss")
    src.resolver.note_live_position()                   # an autopilot position arrives
    assert src.resolver.position().source == "autopilot"
    src.drop("autopilot")
    p = src.resolver.position()
    assert p.source == "remembered" and (p.lat_deg, p.lon_deg, p.alt_m) == AUTOPILOT_SITE


def test_the_field_calibration_says_it_uses_a_remembered_position(tmp_path):
    src = Sources(_remembered(tmp_path, REMEMBERED_SITE, record=False))
    for which in ("config", "gnss", "autopilot"):
        src.drop(which)
    said = []
    host = DaemonMagCalHost(pipeline=None, swap=None, outbound=None, autopilot=src.autopilot,
                            positions=src.resolver, slew=HeadingSlew())
    host.statustext = lambda severity, text: said.append(text)
    host.reference_field()
    assert len(said) == 1 and "remembered (gnss, " in said[0] and "24 h old" in said[0], said


def test_the_autopilot_position_is_not_used_when_the_config_says_so():
    src = Sources()
    src.drop("config")
    src.drop("gnss")
    src.resolver.location = dataclasses.replace(src.resolver.location, use_autopilot_position=False)
    assert src.resolver.position().source == "simulator"


def test_a_position_given_with_a_request_outranks_every_source():
    """MAV_CMD_FIXED_MAG_CAL_YAW's lat/lon is for that request only."""
    src = Sources()
    host = DaemonMagCalHost(pipeline=None, swap=None, outbound=None, autopilot=src.autopilot,
                            positions=src.resolver, slew=HeadingSlew())
    assert host.reference_field(-33.9, 151.2).declination_rad == pytest.approx(
        earth_field(-33.9, 151.2).declination_rad)


def test_the_manual_declination_outranks_every_position_and_a_big_step_is_a_reset():
    src = Sources()
    params = ParamStore(param_specs(Config()))
    resets = []
    told = []
    decl = Declination(params, src.resolver, signal_reset=lambda: resets.append(1))
    decl.set_estimator = told.append
    decl.resolve(initial=True)
    assert decl.source.endswith("(config)") and told == [decl.rad] and resets == [1]   # from 0: a step
    params.set("DECL_DEG", 7.5)
    params.set("DECL_MANUAL", 1)
    decl.resolve()
    assert decl.source == "manual" and decl.rad == pytest.approx(math.radians(7.5)) and len(resets) == 2
    decl.resolve()
    assert len(told) == 2 and len(resets) == 2        # no change, nothing told


def test_a_small_declination_step_is_told_but_is_no_reset_also_across_180_degrees():
    """A step up to DECLINATION_RESET_STEP_RAD (0.5°) changes the estimator's declination without telling the
    autopilot of a heading reset (reset_counter); a bigger one does both. 179.8° → −179.8° is a 0.4° step."""
    params = ParamStore(param_specs(Config()))
    resolver = PositionResolver(LocationConfig(), gnss_position=lambda: None, autopilot=AutopilotState(),
                                simulator=False)
    resets, told = [], []
    decl = Declination(params, resolver, signal_reset=lambda: resets.append(1))
    decl.set_estimator = told.append
    params.set("DECL_MANUAL", 1)
    for deg, resets_after in ((179.8, 1), (-179.8, 1), (-179.4, 1), (-178.8, 2)):
        params.set("DECL_DEG", deg)
        decl.resolve()
        assert decl.rad == pytest.approx(math.radians(deg)) and told[-1] == decl.rad
        assert len(resets) == resets_after, deg


def test_the_declination_follows_a_moving_position_every_update_period():
    """Re-resolved by `tick` once UPDATE_PERIOD_S has passed since the last resolution (a stepped clock), not
    before: a vehicle that moved (or a position that arrived late) gets the declination of where it is."""
    from ahrsd.daemon.declination import UPDATE_PERIOD_S

    t = [100.0]
    src = Sources()
    src.drop("config")
    decl = Declination(ParamStore(param_specs(Config())), src.resolver, signal_reset=lambda: None,
                       clock=lambda: t[0])
    decl.resolve(initial=True)
    assert decl.rad == pytest.approx(earth_field(*GNSS_SITE).declination_rad, abs=1e-12)
    src.gnss = AUTOPILOT_SITE                        # the receiver now reports another place
    t[0] += 0.5 * UPDATE_PERIOD_S
    decl.tick(t[0])
    assert decl.rad == pytest.approx(earth_field(*GNSS_SITE).declination_rad, abs=1e-12)
    t[0] += 0.6 * UPDATE_PERIOD_S
    decl.tick(t[0])
    assert decl.rad == pytest.approx(earth_field(*AUTOPILOT_SITE).declination_rad, abs=1e-12)


def test_the_first_gnss_fix_takes_the_declination_over_at_once():
    """The receiver outranks the autopilot's position (and the remembered one, and the simulator's site): at its
    first fix (`on_gnss_position`, GnssTask's) the declination is the receiver's place at once, not a whole
    UPDATE_PERIOD_S later (a stepped clock that never reaches it)."""
    t = [100.0]
    src = Sources()
    src.drop("config")
    src.gnss = None                                  # no fix yet: the autopilot's position
    decl = Declination(ParamStore(param_specs(Config())), src.resolver, signal_reset=lambda: None,
                       clock=lambda: t[0])
    decl.resolve(initial=True)
    assert decl.rad == pytest.approx(earth_field(*AUTOPILOT_SITE).declination_rad, abs=1e-12)
    src.gnss = GNSS_SITE
    t[0] += 1.0
    decl.on_gnss_position()
    assert decl.rad == pytest.approx(earth_field(*GNSS_SITE).declination_rad, abs=1e-12)


def test_a_broadcast_parameter_request_for_a_name_we_lack_is_not_ours_to_refuse():
    """A ground station asks every component (target_component 0) for the autopilot's parameters: a name we do
    not have is someone else's, so no STATUSTEXT and no refusal counted; addressed to us, it is refused, counted
    and said once."""
    params = ParamStore(param_specs(Config()))
    counters = ServiceCounters()
    outbound = Outbound(Identity(1, 191, mavlink.MAV_TYPE_ONBOARD_CONTROLLER), counters, clock=lambda: 0.0)
    link = KeptLink()
    outbound.endpoints.append(link)
    proto = ParamProtocol(params, outbound, counters, signing_required=lambda: False, spawn=lambda coro: None)
    read = as_if_from(mavlink.MAVLink_param_request_read_message(1, 0, b"SYSID_THISMAV", -1), 255, 190)
    write = as_if_from(mavlink.MAVLink_param_set_message(1, 0, b"SYSID_THISMAV", 3.0,
                                                         mavlink.MAV_PARAM_TYPE_REAL32), 255, 190)
    proto.on_message(link, read, "PARAM_REQUEST_READ", broadcast=True)
    proto.on_message(link, write, "PARAM_SET", broadcast=True)
    assert link.sent == [] and params.rejected_reads == 0 and params.rejected_writes == 0
    proto.on_message(link, read, "PARAM_REQUEST_READ", broadcast=False)
    proto.on_message(link, write, "PARAM_SET", broadcast=False)
    assert [m.get_type() for m in link.sent] == ["STATUSTEXT", "STATUSTEXT"]
    assert params.rejected_reads == 1 and params.rejected_writes == 1


def _action_param_rig(on_change):
    """(params, link, protocol) for one momentary action parameter, MAG_LRN_ACT, whose write calls on_change."""
    from ahrsd.daemon.params import ParamSpec

    params = ParamStore([ParamSpec("MAG_LRN_ACT", 0, 0, 2, "action", integer=True, momentary=True)],
                        on_change=on_change)
    counters = ServiceCounters()
    outbound = Outbound(Identity(1, 191, mavlink.MAV_TYPE_ONBOARD_CONTROLLER), counters, clock=lambda: 0.0)
    link = KeptLink()
    outbound.endpoints.append(link)
    return params, link, ParamProtocol(params, outbound, counters, signing_required=lambda: False,
                                       spawn=lambda coro: None)


def _action_param_write(value: float):
    return as_if_from(mavlink.MAVLink_param_set_message(1, 191, b"MAG_LRN_ACT", value,
                                                        mavlink.MAV_PARAM_TYPE_REAL32), 255, 190)


def test_a_refused_parameter_write_says_its_whole_reason_and_answers_the_value_in_force():
    """The reason a change is refused (the part's ParamError) reaches the operator whole, however long: it used to
    be cut at 50 bytes ("ahrsd: MAG_LRN_ACT 1: Disarm to change the learn")."""
    from ahrsd.daemon.params import ParamError

    reason = "MAG_LRN_ACT 1: Disarm to change the learned iron"

    def refuse(name, value):
        raise ParamError(reason)

    _, link, proto = _action_param_rig(refuse)
    proto.on_message(link, _action_param_write(1.0), "PARAM_SET", broadcast=False)
    texts = [m for m in link.sent if m.get_type() == "STATUSTEXT"]
    assert "".join(m.text.decode() if isinstance(m.text, bytes) else m.text for m in texts) == f"ahrsd: {reason}"
    assert len({m.id for m in texts}) == 1 and texts[0].id != 0
    (value,) = [m for m in link.sent if m.get_type() == "PARAM_VALUE"]
    assert value.param_value == 0.0


def test_an_accepted_action_parameter_write_is_answered_with_the_value_written_then_reads_0():
    """MAG_LRN_ACT = 2 (reset) done: the PARAM_VALUE answering the write carries 2, as a ground station checks its
    write by the answer — MAVProxy 1.8 printed "Failed to set MAG_LRN_ACT to 2 (invalid returned value 0.0)" and sent
    the write again, acting twice or three times (walk27) —; a read afterwards gives 0, the action done once."""
    done = []
    params, link, proto = _action_param_rig(lambda name, value: done.append((name, value)))
    proto.on_message(link, _action_param_write(2.0), "PARAM_SET", broadcast=False)
    assert done == [("MAG_LRN_ACT", 2.0)]
    (value,) = [m for m in link.sent if m.get_type() == "PARAM_VALUE"]
    assert value.param_value == 2.0
    read = as_if_from(mavlink.MAVLink_param_request_read_message(1, 191, b"MAG_LRN_ACT", -1), 255, 190)
    proto.on_message(link, read, "PARAM_REQUEST_READ", broadcast=False)
    assert [m.param_value for m in link.sent if m.get_type() == "PARAM_VALUE"] == [2.0, 0.0]
    assert params.get("MAG_LRN_ACT") == 0.0


def _inbound(tmp_path, resolver, autopilot):
    params = ParamStore(param_specs(Config()), tmp_path)
    counters = ServiceCounters()
    outbound = Outbound(Identity(1, 191, mavlink.MAV_TYPE_ONBOARD_CONTROLLER), counters)
    decl = Declination(params, resolver, signal_reset=lambda: None)
    proto = ParamProtocol(params, outbound, counters, signing_required=lambda: False, spawn=lambda coro: None)
    router = CommandRouter(lambda ep, m: None)
    return InboundDispatch(outbound, autopilot, router, proto, decl, follow_autopilot_id=True), decl, outbound


def test_inbound_takes_the_autopilot_position_and_id(tmp_path):
    autopilot = AutopilotState()
    resolver = PositionResolver(LocationConfig(), gnss_position=lambda: None, autopilot=autopilot, simulator=False)
    inbound, decl, outbound = _inbound(tmp_path, resolver, autopilot)
    decl.resolve(initial=True)
    assert decl.waiting_for_position
    inbound.on_message(None, as_if_from(mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 0, 0, 4, 3), 7, 1))
    assert outbound.identity.system_id == 7 and autopilot.system_id == 7
    inbound.on_message(None, as_if_from(mavlink.MAVLink_global_position_int_message(
        0, 640000000, -220000000, 0, 0, 0, 0, 0, 0), 9, 1))                     # another system: ignored
    assert decl.waiting_for_position
    inbound.on_message(None, as_if_from(mavlink.MAVLink_global_position_int_message(
        0, 640000000, -220000000, 0, 0, 0, 0, 0, 0), 7, 1))
    assert decl.rad == pytest.approx(earth_field(64.0, -22.0, 0.0).declination_rad) and "autopilot" in decl.source


def test_inbound_answers_an_ftp_request_to_us_on_its_endpoint_and_nothing_else(tmp_path):
    """A MAVLink FTP request addressed to us is answered on the endpoint it came from with a NAK (daemon.ftp_nak,
    tested alone in test_ftp_nak_and_broadcast_notice: a ground station stops waiting); one for the autopilot's
    FTP server gets nothing from us."""
    autopilot = AutopilotState()
    resolver = PositionResolver(LocationConfig(), gnss_position=lambda: None, autopilot=autopilot, simulator=False)
    inbound, _, outbound = _inbound(tmp_path, resolver, autopilot)
    us, link = outbound.identity, KeptLink()

    def ftp_request(target_component):
        return as_if_from(mavlink.MAVLink_file_transfer_protocol_message(0, us.system_id, target_component,
                                                                         [7, 0, 3, 4] + [0] * 247), 255, 190)

    inbound.on_message(link, ftp_request(1))                 # to the autopilot's component
    assert link.sent == []
    inbound.on_message(link, ftp_request(us.component_id))
    (reply,) = link.sent
    assert reply.get_type() == "FILE_TRANSFER_PROTOCOL"
    assert (reply.target_system, reply.target_component) == (255, 190)


def test_the_autopilot_hands_every_gps_message_to_its_listeners():
    """The field calibration subscribes; a refused message is still handed on (the listener judges it), and
    a listener that raises does not stop the input handling."""
    ap = AutopilotState()
    seen = []
    ap.add_gnss_listener(lambda m: 1 / 0)
    ap.add_gnss_listener(lambda m: seen.append(m.get_type()))
    ap.on_gps_raw_int(as_if_from(mavlink.MAVLink_gps_raw_int_message(
        0, 3, 510000000, 10000000, 0, 100, 100, 500, 9000, 10), 3), 1.0)
    ap.on_gps_raw_int(as_if_from(mavlink.MAVLink_gps_raw_int_message(
        0, 3, 999999999, 10000000, 0, 100, 100, 500, 9000, 10), 3), 2.0)      # latitude out of range: refused
    ap.on_global_position_int(as_if_from(mavlink.MAVLink_global_position_int_message(
        0, 510000000, 10000000, 0, 0, 100, 0, 0, 0), 3), 3.0)
    assert seen == ["GPS_RAW_INT", "GPS_RAW_INT", "GLOBAL_POSITION_INT"]
    assert ap.rejected_positions == 1 and ap.lat_deg == pytest.approx(51.0)


class _Est:
    flags = EstimateFlags.NONE


class _StubEstimator:
    def update(self, sample):
        return _Est()


def _reader(listeners, ready=None):
    class Source(LiveSource):
        sample_rate_hz = 100.0
        per_sample = False

    return SampleReader(Source(), Pipeline(_StubEstimator(), Calibration.identity()), Health(stale_timeout_s=0.1),
                        ServiceCounters(), listeners,
                        ReaderOutputs(publish=lambda now: None, statustext=lambda sev, text: None,
                                      heading_reset=lambda: None,
                                      ready=lambda: (ready if ready is not None else []).append(1)),
                        poll_hz=100.0)


def test_a_failing_sample_listener_is_dropped_not_fatal():
    listeners = SampleListeners()
    reader = _reader(listeners)
    good = []
    listeners.add(lambda s, e: 1 / 0)
    remove = listeners.add(lambda s, e: good.append(s.counter))
    for i in range(3):
        reader.process([make_sample(i * 0.001, [0, 0, 0], [0, 0, -9.8], [20, 0, 40], counter=i)], float(i))
    assert good == [0, 1, 2] and len(listeners.fns) == 1
    remove()
    assert listeners.fns == []


def test_the_reader_says_ready_once_on_the_first_good_estimate():
    ready = []
    reader = _reader(SampleListeners(), ready=ready)
    for i in range(3):
        reader.process([make_sample(i * 0.01, [0, 0, 0], [0, 0, -9.8], [20, 0, 40], counter=i)], float(i))
    assert ready == [1]


def test_the_health_report_sends_one_heartbeat_a_second_on_a_stepped_clock():
    class Counts:
        samples = 0

    class Notifier:
        def __init__(self):
            self.statuses, self.watchdogs = [], 0

        def status(self, text):
            self.statuses.append(text)

        def watchdog(self):
            self.watchdogs += 1

    outbound = Outbound(Identity(1, 191, mavlink.MAV_TYPE_ONBOARD_CONTROLLER), ServiceCounters(),
                        clock=lambda: 0.0)
    link = KeptLink()
    outbound.endpoints.append(link)
    notifier = Notifier()
    report = HealthReport(Health(stale_timeout_s=0.1), outbound, notifier, Counts(), watchdog_interval_s=2.0,
                          start=100.0)
    for k in range(101):
        report(100.0 + 0.1 * k)                       # 10 s of housekeeping at 10 Hz
    sent = [m.get_type() for m in link.sent]
    assert sent.count("HEARTBEAT") == 10
    assert sent.count("STATUSTEXT") == 1 and notifier.statuses == ["BOOT: waiting for the sensor"]
    assert notifier.watchdogs == 0                    # no samples flow: systemd must be able to restart us


def test_the_watchdog_goes_out_once_an_interval_while_samples_flow_on_a_stepped_clock():
    """WATCHDOG=1 every watchdog_interval_s while samples flow (sd_watchdog_enabled(3)): with a 2 s interval,
    10 s at 8 Hz sends one at 100, 102, ..., 110 s (6); after the samples stop, none."""
    class Counts:
        samples = 0

    class Notifier:
        def __init__(self):
            self.watchdogs = 0

        def status(self, text):
            pass

        def watchdog(self):
            self.watchdogs += 1

    outbound = Outbound(Identity(1, 191, mavlink.MAV_TYPE_ONBOARD_CONTROLLER), ServiceCounters(),
                        clock=lambda: 0.0)
    health, notifier = Health(stale_timeout_s=0.5), Notifier()
    report = HealthReport(health, outbound, notifier, Counts(), watchdog_interval_s=2.0, start=100.0)
    for k in range(81):                               # steps of 0.125 s: exact in binary
        health.sample_read(100.0 + 0.125 * k)
        report(100.0 + 0.125 * k)
    assert notifier.watchdogs == 6
    for k in range(1, 41):                            # 5 s on: the reader looks and finds nothing
        health.empty_read(110.0 + 0.125 * k)
        report(110.0 + 0.125 * k)
    assert notifier.watchdogs == 6


def test_heading_resets_count_and_end_a_slew():
    resets = HeadingResets(HeadingSlew(max_rate_deg_s=5.0), reset_counter=3)
    resets.slew.start_transition()
    assert resets.slew.active
    resets.signal()
    assert resets.reset_counter == 4 and not resets.slew.active


def test_the_polled_reader_reports_a_bus_failure_and_keeps_sys_status_flowing():
    """A source read through poll() (a replay, the threaded chip source) that fails once: counted, one
    CRITICAL STATUSTEXT, and the publishers run (SYS_STATUS shows the cleared health bits) before the retry."""
    import asyncio

    from ahrsd.drivers.errors import BusError

    class Source(LiveSource):
        sample_rate_hz = 100.0
        per_sample = False
        finished = False

        def __init__(self):
            self.polls = 0

        def poll(self):
            self.polls += 1
            if self.polls == 1:
                raise BusError("SPI transfer failed")
            self.finished = True
            return []

    published, texts, done = [], [], []
    counters = ServiceCounters()
    reader = SampleReader(Source(), Pipeline(_StubEstimator(), Calibration.identity()), Health(stale_timeout_s=0.1),
                          counters, SampleListeners(),
                          ReaderOutputs(publish=published.append, statustext=lambda sev, t: texts.append((sev, t)),
                                        heading_reset=lambda: None, ready=lambda: None,
                                        finished=lambda: done.append(1)),
                          poll_hz=100.0)
    async def run():
        await reader.run(asyncio.get_running_loop())

    asyncio.run(run())
    assert counters.driver_errors == 1 and done == [1]
    assert texts == [(mavlink.MAV_SEVERITY_CRITICAL, "ahrsd: sensor failure: SPI transfer failed")]
    assert len(published) == 1                        # after the failure; none after the last (finished) poll


def test_critical_needs_the_reader_to_find_no_sample_not_only_a_busy_event_loop():
    """`ahrsd run --replay` at load 16 said "CRITICAL: no samples from the sensor" once at the start: the first
    batch kept the event loop busy past stale_timeout_s, and the housekeeping tick that ran first found the last
    sample "old". Stepped clock through the real reader (SampleReader.step) and health report: a busy loop is
    not a missing sample; a look that finds none when one is overdue is (CRITICAL within two ticks), and so is
    a reader that stopped looking (READER_SILENT_TICKS). (Broken by judging by the clock alone, as before: the
    busy start sends CRITICAL.)"""
    from ahrsd.daemon.health import READER_SILENT_TICKS

    class Clock:
        t = 0.0

        def time(self):
            return self.t

    class Timer:
        def arm(self, t):
            pass

    class Source(LiveSource):
        sample_rate_hz = 100.0
        per_sample = True
        stalled = False

        def read_one(self, now):
            return None if self.stalled else make_sample(now, [0, 0, 0], [0, 0, -9.8], [20, 0, 40])

        def next_read_time(self):
            return 0.0

    class Link:
        def send(self, msg):
            if msg.get_type() == "STATUSTEXT":
                texts.append((clock.t, msg.text))
            return True

        def send_together(self, msgs):
            return all([self.send(m) for m in msgs])

    class Notifier:
        def status(self, text):
            pass

        def watchdog(self):
            pass

    texts = []
    clock, source, health = Clock(), Source(), Health(stale_timeout_s=0.1)
    reader = SampleReader(source, Pipeline(_StubEstimator(), Calibration.identity()), health, ServiceCounters(),
                          SampleListeners(), ReaderOutputs(publish=lambda now: None, statustext=lambda sev, t: None,
                                                           heading_reset=lambda: None, ready=lambda: None),
                          poll_hz=100.0)
    reader.loop, reader.timer, reader.period_s = clock, Timer(), 0.01
    outbound = Outbound(Identity(1, 191, mavlink.MAV_TYPE_ONBOARD_CONTROLLER), ServiceCounters(), clock=clock.time)
    outbound.endpoints.append(Link())
    report = HealthReport(health, outbound, Notifier(), reader.pipeline.counters, watchdog_interval_s=None, start=0.0)

    def run_until(end, reader_looks=True):
        while clock.t < end - 1e-9:
            clock.t = round(clock.t + 0.01, 6)
            if reader_looks:
                reader.step()
            if round(clock.t * 100) % 10 == 0:
                report(clock.t)

    report(0.0)
    reader.step()                                   # the first sample, then the loop is busy for 0.5 s
    clock.t = 0.5
    for _ in range(3):                              # the housekeeping ticks it owes run before the reader
        report(clock.t)
    run_until(2.0)
    assert not any("CRITICAL" in t for _, t in texts), texts
    source.stalled = True                           # the sensor stops at 2.0
    run_until(3.0)
    critical = [t for t, text in texts if "CRITICAL" in text]
    assert critical and 2.1 <= critical[0] <= 2.2 + 1e-9, texts
    source.stalled = False
    run_until(4.0)
    assert "ACTIVE" in texts[-1][1]
    run_until(5.0, reader_looks=False)              # the reader stops looking at 4.0
    critical = [t for t, text in texts if "CRITICAL" in text and t > 4.0]
    assert critical and critical[0] <= 4.0 + 0.1 * (READER_SILENT_TICKS + 1) + 1e-9, texts


def test_a_late_housekeeping_tick_does_not_slow_the_heartbeat():
    """Housekeeping runs on absolute 10 Hz deadlines, but a busy event loop runs each tick late (here 0 to 90 ms,
    seeded): the heartbeat stays on its 1 s grid, 100 in 100 s, not one second after each late tick (~95)."""
    import random

    class Counts:
        samples = 0

    class Notifier:
        def status(self, text):
            pass

        def watchdog(self):
            pass

    link = KeptLink()
    outbound = Outbound(Identity(1, 191, mavlink.MAV_TYPE_ONBOARD_CONTROLLER), ServiceCounters(),
                        clock=lambda: 0.0)
    outbound.endpoints.append(link)
    report = HealthReport(Health(stale_timeout_s=0.1), outbound, Notifier(), Counts(), watchdog_interval_s=None,
                          start=100.0)
    rng = random.Random(3)
    for k in range(1000):
        report(100.0 + 0.1 * k + 0.09 * rng.random())
    assert [m.get_type() for m in link.sent].count("HEARTBEAT") in (99, 100)


def test_a_sensor_failure_during_a_calibration_is_critical_not_calibrating():
    health = Health(stale_timeout_s=1.0)
    health.sample_read(0.0)
    health.last_estimate_flags = EstimateFlags.NONE
    health.calibrating = "gyro calibration"
    assert health.system_status(0.5) == mavlink.MAV_STATE_CALIBRATING
    health.sensor_error = "bus failure"
    assert health.system_status(0.5) == mavlink.MAV_STATE_CRITICAL
