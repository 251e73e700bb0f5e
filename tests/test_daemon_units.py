"""Unit tests of the daemon's parts: command routing/ACK rules, parameters, output schedule, message
builders, routing rule, sample timing, sd_notify, and the MAVLink endpoint's handling of malformed input."""

from __future__ import annotations

import asyncio
import logging
import math
import socket

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ahrsd.daemon import messages as msgs
from ahrsd.daemon.commands import CommandAck, CommandRouter
from ahrsd.daemon.mavlink_io import Endpoint, is_for_us, mavlink
from ahrsd.daemon.notify import Notifier, watchdog_interval_s
from ahrsd.daemon.outputs import OutputSchedule
from ahrsd.daemon.params import ParamSpec, ParamStore
from ahrsd.daemon.pipeline import mounting_matrix
from ahrsd.drivers.sample_timer import SampleTimer
from ahrsd.core.sample import make_sample
from support.mavlink_feed import as_if_from

# ------------------------------------------------------------------------------------------ command router


def command(cmd, *params, src=(255, 190), signed=False, target=(1, 200), int_form=False):
    p = list(params) + [0.0] * (7 - len(params))
    if int_form:
        m = mavlink.MAVLink_command_int_message(target[0], target[1], 0, cmd, 0, 0, *p[:4], int(p[4]), int(p[5]),
                                                p[6])
    else:
        m = mavlink.MAVLink_command_long_message(target[0], target[1], cmd, 0, *p)
    as_if_from(m, *src)
    m._signed = signed
    return m


@pytest.fixture
def router():
    sent = []
    clock = [100.0]
    r = CommandRouter(send_ack=lambda ep, m: sent.append(m), clock=lambda: clock[0])
    r.sent, r.now = sent, clock
    return r


def test_unknown_targeted_command_is_unsupported_and_ack_targets_requester(router):
    router.handle(command(4242), "ep", broadcast=False)
    (ack,) = router.sent
    assert (ack.command, ack.result) == (4242, mavlink.MAV_RESULT_UNSUPPORTED)
    assert (ack.target_system, ack.target_component) == (255, 190)


def test_broadcast_commands(router):
    router.handle(command(4242, target=(1, 0)), "ep", broadcast=True)
    assert router.sent == [] and router.counters.ignored_broadcast == 1
    router.register(7, lambda m, c: mavlink.MAV_RESULT_ACCEPTED, accept_broadcast=False)
    router.handle(command(7, target=(1, 0)), "ep", broadcast=True)
    assert router.sent == []
    router.register(8, lambda m, c: mavlink.MAV_RESULT_ACCEPTED)
    router.handle(command(8, target=(1, 0)), "ep", broadcast=True)
    assert router.sent[-1].result == mavlink.MAV_RESULT_ACCEPTED
    router.accept_broadcast = False                    # the daemon's policy ([mavlink] accept_broadcast_commands)
    router.handle(command(8, 2, target=(1, 0)), "ep", broadcast=True)
    assert len(router.sent) == 1 and router.counters.ignored_broadcast == 3


def test_duplicates_are_not_re_executed(router):
    calls = []
    router.register(9, lambda m, c: calls.append(c) or CommandAck(mavlink.MAV_RESULT_IN_PROGRESS, 0))
    router.handle(command(9, 1), "ep", False)
    router.handle(command(9, 1), "ep", False)             # the re-send
    assert len(calls) == 1 and [a.result for a in router.sent] == [mavlink.MAV_RESULT_IN_PROGRESS] * 2
    calls[0].finish(mavlink.MAV_RESULT_ACCEPTED)
    router.handle(command(9, 1), "ep", False)             # a late duplicate gets the final result
    assert len(calls) == 1 and router.sent[-1].result == mavlink.MAV_RESULT_ACCEPTED
    router.handle(command(9, 2), "ep", False)             # different parameters: a new command
    assert len(calls) == 2
    router.now[0] += 10.0                                 # outside the duplicate window: executed again
    router.handle(command(9, 1), "ep", False)
    assert len(calls) == 3
    assert router.counters.duplicates == 2


def test_a_temporarily_rejected_command_retried_is_evaluated_afresh(router):
    """TEMPORARILY_REJECTED ("disarm first") is not what a retry within the duplicate window gets: the operator
    disarms and re-sends, and the command runs."""
    armed = [True]
    calls = []

    def handler(m, c):
        calls.append(1)
        return mavlink.MAV_RESULT_TEMPORARILY_REJECTED if armed[0] else mavlink.MAV_RESULT_ACCEPTED

    router.register(13, handler)
    router.handle(command(13, 1), "ep", False)
    armed[0] = False
    router.now[0] += 1.0
    router.handle(command(13, 1), "ep", False)
    assert len(calls) == 2 and [a.result for a in router.sent] == [mavlink.MAV_RESULT_TEMPORARILY_REJECTED,
                                                                   mavlink.MAV_RESULT_ACCEPTED]


def test_a_command_resent_every_second_runs_once(router):
    """A ground station that keeps re-sending (every 1 s, longer than the 3 s window): each re-send is a duplicate
    of the one before, so the command runs once (the window restarts at every duplicate)."""
    calls = []
    router.register(14, lambda m, c: calls.append(1) or mavlink.MAV_RESULT_ACCEPTED)
    for k in range(8):
        router.now[0] = 100.0 + k
        router.handle(command(14, 1), "ep", False)
    assert len(calls) == 1 and router.counters.duplicates == 7


def test_a_flood_of_refusals_is_logged_and_said_a_bounded_number_of_times(caplog):
    """100 refused commands at one instant: REFUSAL_LOG_BURST warnings and STATUSTEXTs, the rest counted."""
    from ahrsd.daemon.commands import REFUSAL_LOG_BURST, Refused

    said = []
    router = CommandRouter(send_ack=lambda ep, m: None, statustext=lambda severity, text: said.append(text),
                           clock=lambda: 100.0)
    router.register(15, lambda m, c: Refused(mavlink.MAV_RESULT_DENIED, "no"))
    caplog.set_level(logging.WARNING, logger="ahrsd.daemon.commands")
    for k in range(100):
        router.handle(command(15, k), "ep", False)
    assert router.counters.refused == 100 and len(said) == REFUSAL_LOG_BURST
    assert router.counters.refusal_logs_suppressed == 100 - REFUSAL_LOG_BURST
    assert sum("refused" in r.getMessage() for r in caplog.records) == REFUSAL_LOG_BURST


def test_read_only_commands_are_answered_again(router):
    calls = []
    router.register(10, lambda m, c: calls.append(1) or mavlink.MAV_RESULT_ACCEPTED, state_changing=False)
    router.handle(command(10, 1), "ep", False)
    router.handle(command(10, 1), "ep", False)
    assert len(calls) == 2


def test_signing_policy_and_handler_failure(router):
    router.require_signed = lambda: True
    ran = []
    router.register(11, lambda m, c: ran.append(1) or mavlink.MAV_RESULT_ACCEPTED)
    router.handle(command(11), "ep", False)
    assert router.sent[-1].result == mavlink.MAV_RESULT_DENIED and not ran
    router.handle(command(11, signed=True), "ep", False)   # a signed retry is evaluated afresh
    assert router.sent[-1].result == mavlink.MAV_RESULT_ACCEPTED and ran
    assert router.counters.unsigned_refused == 1

    def boom(m, c):
        raise RuntimeError("bug")
    router.register(12, boom)
    router.handle(command(12, signed=True), "ep", False)
    assert router.sent[-1].result == mavlink.MAV_RESULT_FAILED and router.counters.handler_errors == 1


def test_command_int_params(router):
    seen = []
    router.register(13, lambda m, c: seen.append((c.is_command_int, m.x)) or mavlink.MAV_RESULT_ACCEPTED)
    router.handle(command(13, 0, 0, 0, 0, 5, 6, 7, int_form=True), "ep", False)
    assert seen == [(True, 5)]


def test_routing_rule():
    def m(ts, tc):
        return mavlink.MAVLink_command_long_message(ts, tc, 1, 0, 0, 0, 0, 0, 0, 0, 0)
    assert is_for_us(m(0, 0), 1, 200) == (True, True)
    assert is_for_us(m(1, 0), 1, 200) == (True, True)
    assert is_for_us(m(1, 200), 1, 200) == (True, False)
    assert is_for_us(m(1, 1), 1, 200) == (False, False)
    assert is_for_us(m(2, 200), 1, 200) == (False, False)
    assert is_for_us(mavlink.MAVLink_heartbeat_message(1, 8, 0, 0, 0, 3), 1, 200) == (True, True)

# ------------------------------------------------------------------------------------------ parameters


def test_param_store_validates_persists_and_reloads(tmp_path):
    applied = []
    specs = [ParamSpec("SR_A", 10, 0, 50, "Hz"), ParamSpec("FLAG", 0, 0, 1, "0/1", integer=True)]
    p = ParamStore(specs, tmp_path, on_change=lambda n, v: applied.append((n, v)))
    assert p.set("SR_A", 60) == (False, "SR_A: 60 outside [0, 50]")
    assert p.set("SR_A", float("nan"))[0] is False
    assert p.set("FLAG", 0.5)[0] is False
    assert p.set("NOPE", 1)[0] is False
    assert p.get("SR_A") == 10 and applied == []
    assert p.set("SR_A", 20) == (True, "")
    assert applied == [("SR_A", 20.0)]
    q = ParamStore(specs, tmp_path)
    assert q.load() == [] and q.get("SR_A") == 20.0 and q.get("FLAG") == 0.0
    (tmp_path / "params.json").write_text('{"schema": 1, "values": {"SR_A": 99, "GONE": 1}}')
    r = ParamStore(specs, tmp_path)
    warnings = r.load()
    assert len(warnings) == 2 and r.get("SR_A") == 10
    (tmp_path / "params.json").write_text("{broken")
    assert ParamStore(specs, tmp_path).load()[0].startswith("ignoring parameter file")


def test_a_parameter_range_includes_both_ends():
    """[lo, hi] is closed, as the range the refusal names: DECL_MANUAL's 1 and 0 are the values it has."""
    p = ParamStore([ParamSpec("SR_A", 10, 0, 50, "Hz"), ParamSpec("FLAG", 0, 0, 1, "0/1", integer=True)])
    assert p.set("SR_A", 0.0) == (True, "") and p.set("SR_A", 50.0) == (True, "")
    assert p.set("FLAG", 1.0) == (True, "") and p.set("FLAG", 0.0) == (True, "")
    assert p.set("SR_A", -1e-9)[0] is False and p.set("SR_A", 50.000001)[0] is False
    assert p.get("SR_A") == 50.0


def test_param_names_and_defaults_are_checked():
    with pytest.raises(ValueError):
        ParamSpec("THIS_NAME_IS_TOO_LONG", 0, 0, 1, "")
    with pytest.raises(ValueError):
        ParamSpec("X", 5, 0, 1, "")

# ------------------------------------------------------------------------------------------ output schedule


def test_schedule_rates_and_interval_semantics():
    s = OutputSchedule({30: 50.0, 102: 30.0, 26: 0.0})
    sent = {30: 0, 102: 0, 26: 0}
    t = 0.0
    while t < 10.0:
        for mid in s.due(t):
            sent[mid] += 1
        t += 0.00122                                     # one wake per ADIS16405 sample
    assert sent[30] == pytest.approx(500, abs=1) and sent[102] == pytest.approx(300, abs=1) and sent[26] == 0
    s.set_interval_us(30, 100_000)
    assert s.interval_us(30) == 100_000 and s.rate_hz(30) == pytest.approx(10.0)
    s.set_interval_us(30, -1)
    assert s.interval_us(30) == -1
    s.set_interval_us(30, 0)
    assert s.rate_hz(30) == 50.0
    with pytest.raises(ValueError):
        s.set_interval_us(102, 10_000)                   # 100 Hz VISION_POSITION_ESTIMATE: above 50 Hz
    with pytest.raises(ValueError):
        s.set_interval_us(30, -5)


def test_schedule_does_not_burst_after_a_stall():
    s = OutputSchedule({30: 50.0})
    assert s.due(0.0) == [30]
    assert s.due(5.0) == [30]           # 5 s stall: one message, not 250
    assert s.due(5.001) == []


def test_schedule_counts_the_deadlines_a_restart_skips():
    # a 64 Hz stream woken every 1/256 s for 3 s with a 1 s stall from 1.0 s (binary-exact times: every count
    # below is exact). The deadlines that passed are the grid k/64 s, k = 0 … 192 (the restart at 2.0 s lands
    # on it): each must be sent or counted dropped, none twice
    s = OutputSchedule({30: 64.0})
    sent = 0
    for k in range(3 * 256 + 1):
        if not 256 < k < 512:
            sent += len(s.due(k / 256))
    dropped = s.dropped_slots()[30]
    assert sent + dropped == 193
    # the stall's 64 deadlines in (1.0, 2.0], less the one the wake at 2.0 s sent (65/64 s)
    assert dropped == 63
    skip, = s.skips
    assert (skip.message_id, skip.first_due_s, skip.period_s, skip.count) == (30, 66 / 64, 1 / 64, 63)


# ------------------------------------------------------------------------------------------ message builders


class Est:
    def __init__(self, q, rpy, rate=(0.1, -0.2, 0.3), sigma=(0.01, 0.02, 0.05)):
        self.q_wxyz = np.array(q)
        self.roll_rad, self.pitch_rad, self.yaw_rad = rpy
        self.heading_true_rad = rpy[2]
        self.rate_body_rad_s = np.array(rate)
        self.sigma_rpy_rad = np.array(sigma)
        self.t_s = 1.0


@settings(derandomize=True, max_examples=200, deadline=None)
@given(st.floats(-3.1, 3.1), st.floats(-1.5, 1.5), st.floats(-3.1, 3.1), st.floats(-0.5, 0.5))
def test_true_quaternion_adds_declination_to_yaw(roll, pitch, yaw, decl):
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_quat()
    q = msgs.true_quaternion(np.array([w, x, y, z]), decl)
    r = Rotation.from_quat([q[1], q[2], q[3], q[0]])
    yaw2, pitch2, roll2 = r.as_euler("ZYX")
    assert abs(math.remainder(yaw2 - (yaw + decl), 2 * math.pi)) < 1e-9
    assert abs(pitch2 - pitch) < 1e-9


def test_vision_position_estimate_fields():
    m = msgs.vision_position_estimate(Est([1, 0, 0, 0], (0.1, 0.2, 3.5)), 123, 3.5, 257)
    assert (m.x, m.y, m.z) == (0.0, 0.0, 0.0)
    assert m.yaw == pytest.approx(3.5 - 2 * math.pi)
    assert m.covariance[20] == pytest.approx(0.05 ** 2) and m.covariance[15] == pytest.approx(0.01 ** 2)
    assert m.covariance[0] == m.covariance[6] == m.covariance[11] == msgs.VPE_POSITION_VARIANCE_M2
    assert m.covariance[1] == 0.0 and m.reset_counter == 1                     # wraps at 256
    inf = msgs.vision_position_estimate(Est([1, 0, 0, 0], (0, 0, 0), sigma=(0, 0, float("inf"))), 1, 0, 0)
    assert all(math.isfinite(c) for c in inf.covariance)


def test_imu_messages_units_and_clipping():
    s = make_sample(0.0, [0.1, -0.2, 40.0], [0.0, 0.0, -9.80665], [20.0, -5.0, 45.0], temp_c=0.0)
    h = msgs.highres_imu(s, 5)
    assert (h.xmag, h.ymag, h.zmag) == pytest.approx((0.2, -0.05, 0.45))      # µT → gauss
    assert h.zgyro == pytest.approx(40.0) and h.fields_updated == 0x11FF
    si = msgs.scaled_imu(s, 1)
    assert si.zacc == -1000 and si.xgyro == 100 and si.zgyro == 32767          # mG, mrad/s, clipped int16
    assert (si.xmag, si.ymag, si.zmag) == (200, -50, 450) and si.temperature == 1   # "at 0 °C send 1"
    nan_t = msgs.highres_imu(make_sample(0, [0] * 3, [0] * 3, [0] * 3), 1)
    assert nan_t.fields_updated == 0x11FF & ~0x1000


def test_mounting_matrix():
    assert mounting_matrix([0, 0, 0]) is None
    m = mounting_matrix([0, 0, 90])
    assert m @ np.array([1.0, 0, 0]) == pytest.approx([0, 1, 0])     # sensor x along body y
    m = mounting_matrix([180, 0, 0])
    assert m @ np.array([0, 0, 1.0]) == pytest.approx([0, 0, -1])    # upside down

# ------------------------------------------------------------------------------------------ sample timing


def simulate_reads(phase, period, n_samples, lateness, reads_per_sample):
    """Drive a SampleTimer like the reader does, against a chip that keeps only its latest sample."""
    timer = SampleTimer(period)
    t = phase + 0.3 * period
    got = []          # (true index, timer index, t_s, lost, ambiguous samples counted so far)
    rng = np.random.default_rng(1)
    for _ in range(n_samples * reads_per_sample):
        true_k = math.floor((t - phase) / period)
        if got and true_k == got[-1][0]:
            timer.stale(t)
        else:
            t_s, k, lost = timer.fresh(t)
            got.append((true_k, k, t_s, lost, timer.ambiguous_samples))
        target = timer.next_read_time()
        # asyncio: wake after the deadline, within the 1 ms selector tick plus jitter
        t = max(target, t + 1e-5) + rng.uniform(0, lateness)
        if len(got) >= n_samples:
            break
    return got


@settings(derandomize=True, max_examples=60, deadline=None)
@given(st.floats(0, 1e-3), st.floats(0, 0.9e-3))
def test_sample_timer_indices_and_time_stamps(phase, lateness):
    period = 1 / 819.2
    got = simulate_reads(phase, period, 2000, lateness, 3)
    true_k = np.array([g[0] for g in got])
    k = np.array([g[1] for g in got])
    # The index counts exactly the chip's samples (lost ones included), except at reads the timer itself
    # reports as ambiguous: there it takes the largest index allowed, so the offset to the truth is never
    # negative (a hidden loss) and never more than the ambiguous samples it counted (phantom losses).
    offset, ambiguous = index_offsets(got)
    assert np.all(offset >= 0)
    assert np.all(offset <= ambiguous)
    # time stamps lie on the sample grid, never before the true ready time by more than the guard, and
    # (once locked) within a fraction of a period of it, even when every wake is late
    t_s = np.array([g[2] for g in got])
    err = t_s - (phase + true_k * period)
    assert np.all(err[50:] > -SampleTimer.GUARD_S)
    assert np.median(np.abs(err[50:])) < 0.1e-3
    assert np.max(np.abs(err[1000:])) < 0.25 * period


def index_offsets(got):
    """(daemon index − chip index) at every fresh read, counted from the first read, and the ambiguous samples
    the timer had reported by then."""
    true_k = np.array([g[0] for g in got])
    k = np.array([g[1] for g in got])
    ambiguous = np.array([g[4] for g in got])
    return (k - k[0]) - (true_k - true_k[0]), ambiguous


@settings(derandomize=True, max_examples=30, deadline=None)
@given(st.floats(0, 1e-3), st.floats(1.5e-3, 3e-3))
def test_sample_timer_counts_every_sample_lost_to_late_wakes(phase, lateness):
    """Wakes up to 2.5 periods late lose samples on the chip: every one is counted (the offset to the chip's
    index never goes negative), and over-counting stays within the ambiguity the timer reports."""
    got = simulate_reads(phase, 1 / 819.2, 2000, lateness, 3)
    offset, ambiguous = index_offsets(got)
    assert sum(g[3] for g in got) > 100                 # the wakes really lost samples
    assert np.all(offset >= 0)
    assert np.all(offset <= ambiguous)


def test_sample_timer_counts_a_long_stall():
    period = 0.001
    timer = SampleTimer(period)
    timer.fresh(0.0002)
    for i in range(1, 20):
        timer.fresh(i * period + 0.0002)
    t_s, k, lost = timer.fresh(30 * period + 0.0002)
    assert (k, lost) == (30, 10)
    assert t_s == pytest.approx(30 * period + 0.0002, abs=2e-4)

# ------------------------------------------------------------------------------------------ sd_notify


def test_notifier_path_and_abstract_sockets(tmp_path):
    path = tmp_path / "n.sock"
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    srv.bind(str(path))
    n = Notifier({"NOTIFY_SOCKET": str(path)})
    assert n.ready("ok") and n.watchdog() and n.stopping()
    assert srv.recv(100) == b"READY=1\nSTATUS=ok"
    assert srv.recv(100) == b"WATCHDOG=1"
    assert srv.recv(100) == b"STOPPING=1"
    srv.close()
    abstract = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    name = f"ahrsd-test-{id(abstract)}"
    abstract.bind("\0" + name)
    assert Notifier({"NOTIFY_SOCKET": "@" + name}).notify("STATUS=x")
    assert abstract.recv(100) == b"STATUS=x"
    abstract.close()
    quiet = Notifier({})
    assert not quiet.enabled and not quiet.ready()
    gone = Notifier({"NOTIFY_SOCKET": str(tmp_path / "missing.sock")})
    assert not gone.ready() and not gone.watchdog() and gone.failures == 2   # counted, never raised


def test_watchdog_interval():
    import os

    assert watchdog_interval_s({"WATCHDOG_USEC": "5000000"}) == 2.5
    assert watchdog_interval_s({}) is None
    assert watchdog_interval_s({"WATCHDOG_USEC": "x"}) is None
    assert watchdog_interval_s({"WATCHDOG_USEC": "5000000", "WATCHDOG_PID": "1"}) is None
    assert watchdog_interval_s({"WATCHDOG_USEC": "5000000", "WATCHDOG_PID": str(os.getpid())}) == 2.5

# ------------------------------------------------------------------------------------------ endpoint input


def test_endpoint_counts_malformed_input_and_delivers_good_messages():
    async def scenario():
        loop = asyncio.get_running_loop()
        got = []
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            probe.bind(("127.0.0.1", 0))
            port = probe.getsockname()[1]
        ep = Endpoint(f"udpin:127.0.0.1:{port}", 1, 200, lambda e, m: got.append(m.get_type()))
        ep.open(loop)
        sender = mavlink.MAVLink(None, srcSystem=9, srcComponent=1)
        good = sender.heartbeat_encode(2, 3, 0, 0, 4).pack(sender)
        bad_crc = bytearray(sender.heartbeat_encode(2, 3, 0, 0, 4).pack(sender))
        bad_crc[-2] ^= 0x55
        truncated = good[:7]
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for data in (b"\x00" * 40, bytes(bad_crc), good, truncated, bytes(range(256)), good + good):
                s.sendto(data, ("127.0.0.1", port))
                await asyncio.sleep(0.01)
        await asyncio.sleep(0.05)
        ep.close()
        return got, ep.counters

    got, counters = asyncio.run(scenario())
    assert got.count("HEARTBEAT") >= 2
    assert counters.rx_malformed >= 2


def test_endpoint_handler_exception_is_contained():
    async def scenario():
        loop = asyncio.get_running_loop()
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            probe.bind(("127.0.0.1", 0))
            port = probe.getsockname()[1]

        def bad_handler(e, m):
            raise KeyError("bug")
        ep = Endpoint(f"udpin:127.0.0.1:{port}", 1, 200, bad_handler)
        ep.open(loop)
        sender = mavlink.MAVLink(None, srcSystem=9, srcComponent=1)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.sendto(sender.heartbeat_encode(2, 3, 0, 0, 4).pack(sender), ("127.0.0.1", port))
        await asyncio.sleep(0.05)
        ep.close()
        return ep.counters

    counters = asyncio.run(scenario())
    assert counters.rx_messages == 1 and counters.rx_malformed == 1

# ------------------------------------------------------------------------------------------ autopilot inputs


def test_autopilot_state_latches_and_reads_position_course_speed():
    from ahrsd.daemon.autopilot import AutopilotState

    ap = AutopilotState()
    gcs = as_if_from(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0,
                                                       3), 255, 190)
    assert not AutopilotState.is_autopilot_heartbeat(gcs)
    hb = as_if_from(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_SURFACE_BOAT,
                                                      mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                                      mavlink.MAV_MODE_FLAG_SAFETY_ARMED, 0, 4, 3), 3, 1)
    assert AutopilotState.is_autopilot_heartbeat(hb) and ap.on_heartbeat(hb, 1.0)
    assert (ap.system_id, ap.armed) == (3, True)
    ap.on_global_position_int(as_if_from(mavlink.MAVLink_global_position_int_message(
        0, 520000000, 44000000, 12000, 0, 0, 300, 0, 9000), 3), 2.0)          # north-east? vx=0, vy=3 m/s
    assert (ap.lat_deg, ap.lon_deg, ap.alt_m) == pytest.approx((52.0, 4.4, 12.0))
    assert ap.course_rad == pytest.approx(math.pi / 2) and ap.ground_speed_m_s == pytest.approx(3.0)
    ap.on_gps_raw_int(as_if_from(mavlink.MAVLink_gps_raw_int_message(
        0, 3, 510000000, 1000000, 0, 100, 100, 250, 18000, 10), 3), 3.0)       # 2.5 m/s, course 180°
    assert ap.lat_deg == pytest.approx(51.0) and ap.course_rad == pytest.approx(math.pi)
    ap.on_gps_raw_int(as_if_from(mavlink.MAVLink_gps_raw_int_message(
        0, 1, 0, 0, 0, 100, 100, 0, 0, 0), 3), 4.0)                            # no fix: ignored
    assert ap.lat_deg == pytest.approx(51.0)


