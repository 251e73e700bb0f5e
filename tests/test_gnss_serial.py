"""The serial GNSS source reading the simulated receiver through a pseudo-terminal, byte for byte as on
hardware: UBX and NMEA, garbage, truncated frames, a baud mismatch, silence, the device going away."""

import contextlib
import datetime as dt
import select

import numpy as np
import pytest

from ahrsd.core.gnss import GnssFixType, make_fix
from ahrsd.drivers.gnss.serial_port import GnssDeviceError, GnssLinkState, SerialGnssSource
from ahrsd.drivers.gnss.simulated import GPS_EPOCH, SimulatedGnssReceiver, uart_resample


class FakeClock:
    def __init__(self, t=1000.0):
        self.t = t

    def __call__(self):
        return self.t


def _fixes(n=5, t0=0.0):
    return [make_fix(t0 + 0.2 * k, 47.1 + 1e-5 * k, 8.2 - 1e-5 * k, 500.0 + k, [1.25, -2.5, 0.5],
                     h_acc_m=1.5, v_acc_m=2.5, s_acc_m_s=0.25, num_sats=12) for k in range(n)]


@contextlib.contextmanager
def _link(fixes, rx_kw=None, baud=115200, protocol="auto", clock=None, write=True, **src_kw):
    """A simulated receiver on a pty and the serial source reading it; `write`: put every fix on the line."""
    with SimulatedGnssReceiver(fixes, **(rx_kw or {})) as rx, \
            SerialGnssSource(rx.device, baud, protocol, clock=clock or FakeClock(), **src_kw) as src:
        if write:
            for f in fixes:
                rx.write_fix(f)
        yield rx, src


def _read_until(src, want, max_wait_s=5.0):
    """Read until `want` fixes arrived or nothing more comes (a wait, not a timing assertion)."""
    out = []
    while len(out) < want:
        ready, _, _ = select.select([src.fileno()], [], [], max_wait_s)
        if not ready:
            break
        out += src.read_available()
    return out


def _read_all(src, rx, max_wait_s=10.0):
    """Read until every byte the receiver put on the pty has arrived (a wait, not a timing assertion)."""
    out = []
    while src.counters["bytes_in"] < rx.wire_bytes_written:
        if not select.select([src.fileno()], [], [], max_wait_s)[0]:
            break
        out += src.read_available()
    return out


@pytest.mark.parametrize("protocol, source_protocol", [("ubx", "ubx"), ("ubx", "auto"), ("nmea", "nmea"),
                                                        ("nmea", "auto")])
def test_fixes_arrive_intact(protocol, source_protocol):
    fixes = _fixes()
    clock = FakeClock(50.0)
    with _link(fixes, {"protocol": protocol}, protocol=source_protocol, latency_s=0.125, clock=clock,
               write=False) as (rx, src):
        got, arrivals = [], []
        for k, f in enumerate(fixes):                 # each epoch read as it arrives, 0.2 s apart
            clock.t = 50.0 + 0.2 * k
            arrivals.append(clock.t)
            rx.write_fix(f)
            got += _read_all(src, rx)
        got += src.decoder.flush()      # nothing pending once the epoch's sentence set is learned; be sure
        assert len(got) == len(fixes)
        for a, b, arrived in zip(fixes, got, arrivals):
            # arrival on the caller's clock minus the latency (every read on time: the receiver-time stamps agree)
            assert b.t_s == pytest.approx(arrived - 0.125, abs=1e-6)
            assert b.lat_deg == pytest.approx(a.lat_deg, abs=1e-7) and b.lon_deg == pytest.approx(a.lon_deg, abs=1e-7)
            assert b.alt_m == pytest.approx(a.alt_m, abs=1e-3)
            np.testing.assert_allclose(b.vel_ned_m_s[:2], a.vel_ned_m_s[:2], atol=2e-3)
            assert b.fix_type == GnssFixType.FIX_3D and b.num_sats == 12
        if protocol == "ubx":
            assert [b.h_acc_m for b in got] == pytest.approx([1.5] * 5)
            assert [b.vel_ned_m_s[2] for b in got] == pytest.approx([0.5] * 5)
        assert src.state is GnssLinkState.OK
        c = src.counters
        assert c["garbage_bytes"] == 0 and c["frames_rejected"] == 0 and c["bytes_in"] == rx.bytes_written


@pytest.mark.parametrize("protocol", ["ubx", "nmea"])
def test_epochs_read_in_one_burst_keep_their_own_times(protocol):
    """A reader held up for a second finds five epochs waiting: each is stamped by the receiver's own epoch
    times (0.2 s apart) back from the read, so none is refused as a repeated time and none comes late."""
    from ahrsd.drivers.gnss.validation import GnssFixValidator
    fixes = _fixes(5)
    clock = FakeClock(80.0)
    with _link(fixes, {"protocol": protocol}, protocol=protocol, latency_s=0.1, clock=clock) as (rx, src):
        for _ in range(500):                          # every byte in the kernel's buffer: one read takes them all
            if src._serial.in_waiting >= rx.wire_bytes_written:
                break
            select.select([], [], [], 0.01)
        got = src.read_available()
    validator = GnssFixValidator(clock=clock)
    assert [validator.check(f) for f in got] == [None] * 5
    # the last at the read minus the latency; each earlier one 0.2 s (the epochs' spacing) before the next
    assert [f.t_s for f in got] == pytest.approx([80.0 - 0.1 - 0.2 * (4 - k) for k in range(5)], abs=1e-6)


@pytest.mark.parametrize("protocol", ["ubx", "nmea"])
def test_a_held_up_read_then_a_burst_never_stamps_backwards(protocol):
    """Last session's record failure, on the port: epochs read on time, then a read held up 0.68 s that gets
    one epoch, then the three behind it at once. Every epoch is stamped at the time it was sent (its on-time
    arrival minus the latency, from the receiver's epoch times), so the stamps increase and none is refused."""
    from ahrsd.drivers.gnss.validation import GnssFixValidator
    fixes = _fixes(9)
    clock = FakeClock(50.0)
    sent = [50.0 + 0.2 * k for k in range(9)]        # when each epoch's bytes were complete on the host
    with _link(fixes, {"protocol": protocol}, protocol=protocol, latency_s=0.1, clock=clock,
               write=False) as (rx, src):
        got = []
        for k in range(5):
            clock.t = sent[k]
            rx.write_fix(fixes[k])
            got += _read_all(src, rx)
        rx.write_fix(fixes[5])
        clock.t = sent[5] + 0.68                      # the held-up read gets epoch 5 alone
        got += _read_all(src, rx)
        for f in fixes[6:]:
            rx.write_fix(f)
        clock.t += 0.001                              # and the next one the three behind it
        got += _read_all(src, rx)
        got += src.decoder.flush()
        stamps = [f.t_s for f in got]
        assert stamps == pytest.approx([t - 0.1 for t in sent], abs=1e-6)
        validator = GnssFixValidator(clock=clock)
        assert [validator.check(f) for f in got] == [None] * 9
        assert src.counters["stamps_held"] == 0 and src.counters["receiver_clock_jumps"] == 0


@pytest.mark.parametrize("protocol, start_utc", [
    ("ubx", GPS_EPOCH + dt.timedelta(weeks=2400, seconds=-0.4)),       # iTOW wraps at the end of the GPS week
    ("nmea", dt.datetime(2026, 6, 1, 23, 59, 59, 600_000, tzinfo=dt.timezone.utc))])   # UTC at midnight
def test_the_receiver_time_wrap_is_no_clock_jump(protocol, start_utc):
    """Epochs across the wrap of the receiver's time, each read on time: stamped at their arrival (minus the
    latency) without a clock jump: each protocol's time is unwrapped at its own period."""
    fixes = _fixes(5)
    clock = FakeClock(20.0)
    with _link(fixes, {"protocol": protocol, "start_utc": start_utc}, protocol=protocol, latency_s=0.1,
               clock=clock, write=False) as (rx, src):
        got = []
        for k, f in enumerate(fixes):
            clock.t = 20.0 + 0.2 * k
            rx.write_fix(f)
            got += _read_all(src, rx)
        got += src.decoder.flush()
        rx_times = [f.extra["receiver_time_s"] for f in got]
        assert rx_times[2] < rx_times[1]                      # the wrap is there
        assert [f.t_s for f in got] == pytest.approx([20.0 + 0.2 * k - 0.1 for k in range(5)], abs=1e-6)
        assert src.counters["receiver_clock_jumps"] == 0 and src.counters["stamps_held"] == 0


def test_an_epoch_begun_before_a_burst_keeps_its_earlier_time():
    """An NMEA epoch whose first sentence arrived at an earlier read keeps that read's time (the earliest it was
    seen), and the next epoch, read late in a stalled burst, is stamped from it by the receiver's epoch times
    (0.2 s later), not at the stalled read."""
    fixes = _fixes(2)
    clock = FakeClock(10.0)
    with _link(fixes, {"protocol": "nmea"}, protocol="nmea", latency_s=0.1, clock=clock, write=False) as (rx, src):
        first, *rest = rx.frames_for(fixes[0])
        rx.write_bytes(first)                         # the epoch's RMC, seen at 10.0
        assert _read_until(src, 1, max_wait_s=0.5) == []
        clock.t = 10.5                                # the reader then stalls; the rest comes in one go
        rx.write_bytes(b"".join(rest) + b"".join(rx.frames_for(fixes[1])))
        got = _read_all(src, rx)
    assert [f.t_s for f in got] == pytest.approx([10.0 - 0.1, 10.0 - 0.1 + 0.2], abs=1e-6)


def test_garbage_between_frames_is_counted_and_every_fix_survives():
    fixes = _fixes(8)
    with _link(fixes, {"garbage_bytes": 300, "seed": 3}, protocol="ubx") as (rx, src):
        got = _read_all(src, rx)
        assert [g.lat_deg for g in got] == pytest.approx([f.lat_deg for f in fixes], abs=1e-7)
        assert src.counters["garbage_bytes"] >= 8 * 300 - 50     # a few garbage sync bytes count as rejections
        assert src.counters["garbage_bytes"] + 8 * 100 == src.counters["bytes_in"]


def test_truncated_and_corrupted_frames_are_rejected_others_kept():
    fixes = _fixes(9)
    with _link(fixes, {"truncate_every": 3, "corrupt_every": 4}, protocol="ubx") as (rx, src):
        got = _read_all(src, rx)
        kept = [k for k in range(1, 10) if k % 3 and k % 4]       # frames 3, 6, 9 cut, 4 and 8 corrupted
        assert [g.lat_deg for g in got] == pytest.approx([fixes[k - 1].lat_deg for k in kept], abs=1e-7)
        # 3 and 6 fail their checksum (the next frame's bytes complete them), as do 4 and 8; the cut last frame
        # waits in the buffer for bytes that never come
        assert src.counters["checksum_failures"] == 4
        assert src.decoder.buffered_bytes == 50
        assert src.state is GnssLinkState.OK


def test_uart_resample_matches_hand_computed_bits():
    # 0x55 at 9600 read at 19200. The line: start 0, data (LSB first) 1,0,1,0,1,0,1,0, stop 1, idle 1.
    # Each line bit lasts two receiver bits; the receiver samples its data bit k at 1.5+k receiver bits =
    # 0.75+0.5k line bits -> line bits 0,1,1,2,2,3,3,4 = 0,1,1,0,0,1,1,0 -> 0x66. Its stop sample (line bit
    # 4.75) ends that byte; the next falling edge, at line bit 6, starts another: samples at line bits
    # 6,7,7,8,8,9,9,10 = 0,1,1,0,0,1,1,1 -> 0xE6.
    assert uart_resample(b"\x55", 9600, 19200) == b"\x66\xe6"
    # read at 16000: a receiver bit is 0.6 line bits; samples at 0.6·(1.5+k) = 0.9, 1.5, 2.1, 2.7, 3.3, 3.9,
    # 4.5, 5.1 -> line bits 0,1,2,2,3,3,4,5 = 0,1,0,0,1,1,0,1 -> 0xB2; stop sample at 5.7; next start at line
    # bit 6: samples 6.9 ... 11.1 -> line bits 6,7,8,8,9,idle.. = 0,1,0,0,1,1,1,1 (bit 0 first) -> 0xF2.
    assert uart_resample(b"\x55", 9600, 16000) == bytes([0b10110010, 0b11110010])
    assert uart_resample(b"hello", 9600, 9600) == b"hello"
    # 0xFF at 115200 read at 9600: the start bit is a 1/12-bit low pulse, high again at the receiver's
    # mid-start sample: a glitch, not a byte
    assert uart_resample(b"\xff", 115200, 9600) == b""


def test_baud_mismatch_is_reported_as_garbage():
    fixes = _fixes(10)
    clock = FakeClock(0.0)
    with _link(fixes, {"baud": 9600}, clock=clock, write=False) as (rx, src):
        assert rx.reader_baud() == 115200
        for f in fixes[:5]:
            rx.write_fix(f)
        got = _read_all(src, rx)
        assert src.state is GnssLinkState.WAITING       # too early to tell
        clock.t = 5.0
        for f in fixes[5:]:
            rx.write_fix(f)
        got += _read_all(src, rx)
        assert got == [] and src.poll_health() is GnssLinkState.GARBAGE
        assert "baud" in src.status_message and "115200" in src.status_message
        assert src.counters["bytes_in"] > 1000 and src.counters["frames_valid"] == 0


def test_silence_is_reported():
    clock = FakeClock(0.0)
    with _link(_fixes(3), {"silent": True}, clock=clock) as (rx, src):
        assert src.read_available() == []
        assert src.poll_health() is GnssLinkState.WAITING
        clock.t = 10.0
        assert src.poll_health() is GnssLinkState.SILENT and "no bytes" in src.status_message


def test_wrong_protocol_is_reported():
    clock = FakeClock(0.0)
    with _link(_fixes(5), {"protocol": "nmea"}, protocol="ubx", clock=clock, write=False) as (rx, src):
        rx.write_fix(rx.fixes[0])
        assert _read_all(src, rx) == []
        clock.t = 5.0
        for f in rx.fixes[1:]:
            rx.write_fix(f)
        assert _read_all(src, rx) == []
        assert src.poll_health() is GnssLinkState.WRONG_PROTOCOL and "NAV-PVT" in src.status_message


def test_device_gone_never_raises_and_reports():
    clock = FakeClock(0.0)
    rx = SimulatedGnssReceiver(_fixes(2))
    src = SerialGnssSource(rx.device, 115200, clock=clock)
    rx.write_fix(rx.fixes[0])
    assert len(_read_until(src, 1)) == 1
    rx.close()
    assert src.read_available() == [] and src.state is GnssLinkState.DEVICE_ERROR
    assert src.fileno() == -1 and src.read_available() == []
    clock.t = 10.0
    assert src.poll_health() is GnssLinkState.DEVICE_ERROR        # re-open attempted, device still gone
    src.close()


def test_device_back_is_reopened():
    clock = FakeClock(0.0)
    with _link(_fixes(3), clock=clock, write=False) as (rx, src):
        rx.write_fix(rx.fixes[0])
        assert len(_read_until(src, 1)) == 1
        src._serial.close()                      # the port fails under us (as a USB receiver unplugged)
        assert src.read_available() == [] and src.state is GnssLinkState.DEVICE_ERROR
        clock.t = 1.0
        assert src.poll_health() is GnssLinkState.DEVICE_ERROR and src.reopen_count == 0   # waits 2 s
        clock.t = 2.5
        src.poll_health()
        assert src.reopen_count == 1 and src.fileno() >= 0
        rx.write_fix(rx.fixes[1])
        assert len(_read_until(src, 1)) == 1 and src.state is GnssLinkState.OK


def test_missing_device_is_a_clear_error():
    with pytest.raises(GnssDeviceError, match="/dev/does-not-exist"):
        SerialGnssSource("/dev/does-not-exist", 115200)
    with pytest.raises(ValueError, match="protocol"):
        SerialGnssSource("/dev/null", 115200, protocol="sirf")


def test_threaded_receiver_writes_at_the_fix_times():
    import time
    t0 = time.monotonic() + 0.05
    fixes = _fixes(5, t0=t0)
    with SimulatedGnssReceiver(fixes, latency_s=0.01) as rx, \
            SerialGnssSource(rx.device, 115200, "ubx", latency_s=0.0) as src:
        rx.start()
        got = _read_until(src, 5)
        assert [g.lat_deg for g in got] == pytest.approx([f.lat_deg for f in fixes], abs=1e-7)
        assert all(b.t_s >= a.t_s for a, b in zip(fixes, got))    # never before the fix was written


@pytest.mark.parametrize("protocol", ["ubx", "nmea"])
def test_fix_lost_on_the_wire_is_a_counted_rejection(protocol):
    from ahrsd.drivers.gnss.validation import GnssFixValidator
    fixes = _fixes(4)
    fixes[2] = make_fix(fixes[2].t_s, 0.0, 0.0, 0.0, [0.0, 0.0, 0.0], fix_type=GnssFixType.NO_FIX)
    clock = FakeClock(0.0)
    with _link(fixes, {"protocol": protocol}, protocol=protocol, clock=clock, write=False) as (rx, src):
        got = []
        for k, f in enumerate(fixes):          # one epoch per clock tick, as a receiver at 5 Hz
            clock.t = 0.2 * k
            rx.write_fix(f)
            got += _read_all(src, rx)
        got += src.decoder.flush()
        assert [g.fix_type for g in got] == [GnssFixType.FIX_3D] * 2 + [GnssFixType.NO_FIX, GnssFixType.FIX_3D]
        validator = GnssFixValidator()
        assert [validator.check(g) for g in got] == [None, None, "no_fix", None]
        assert validator.counters["no_fix"] == 1 and validator.counters["accepted"] == 3
