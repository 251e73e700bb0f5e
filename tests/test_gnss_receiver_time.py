"""Fix stamps from the receiver's epoch time (drivers/gnss/receiver_time.py), on a stepped clock: a receiver
sends epoch k at true host time T_k (its own clock reads T_k + its offset), the bytes are in the host's buffer
L later, and the reader takes them at its read times (held up or not); the driver's arrival stamp is
read time − L. Every stamp is judged against the true T_k of this simulation, never against the stamper."""

import math

import numpy as np
import pytest

from ahrsd.core.gnss import make_fix
from ahrsd.drivers.gnss import receiver_time
from ahrsd.drivers.gnss.receiver_time import ReceiverTimeStamper

WEEK_S = 7 * 86400.0
DAY_S = 86400.0
SPACING_S = 0.2          # a 5 Hz receiver
LATENCY_S = 0.1          # the output latency the driver knows (the bytes are complete L after the epoch)


def _fix(arrival_stamp_s, receiver_time_s):
    extra = {} if receiver_time_s is None else {"receiver_time_s": receiver_time_s}
    return make_fix(arrival_stamp_s, 47.0, 8.0, 500.0, [1.0, 0.0, 0.0], num_sats=9, extra=extra)


def _run(true_t_s, receiver_t_s, reads, period_s=WEEK_S):
    """Stamp the epochs (true host times `true_t_s`, receiver times `receiver_t_s`) as a reader gets them:
    `reads` are read times, or (read time, n) for a read that gets at most n epochs (a chunk split); a read
    takes the epochs complete by then. Returns (stamper, stamps in epoch order, reads that returned some)."""
    stamper = ReceiverTimeStamper(period_s)
    stamps, k, n_reads = [], 0, 0
    for read in reads:
        r, limit = read if isinstance(read, tuple) else (read, len(true_t_s))
        batch = []
        while k < len(true_t_s) and true_t_s[k] + LATENCY_S <= r and len(batch) < limit:
            batch.append(_fix(r - LATENCY_S, receiver_t_s[k]))
            k += 1
        if batch:
            n_reads += 1
            stamps += [f.t_s for f in stamper.stamp_read(batch)]
    assert k == len(true_t_s), "every epoch read"
    return stamper, np.array(stamps), n_reads


def _on_time_reads(true_t_s, jitter_s):
    """One read per epoch, `jitter_s[k]` after its bytes were complete."""
    return [t + LATENCY_S + j for t, j in zip(true_t_s, jitter_s)]


def _epochs(n, t0=100.0, rx0=345600.0):
    true_t = t0 + SPACING_S * np.arange(n)
    return true_t, rx0 + (true_t - t0)


def test_a_burst_after_a_held_up_read_keeps_every_epoch_at_its_time():
    """Last session's failure: a read held up 0.68 s returns one epoch, the next read right after it the three
    that piled up behind. Each is stamped at its true time (plus the least delay seen), in order."""
    true_t, rx = _epochs(40)
    jitter = np.full(40, 0.004)
    held = true_t[20] + LATENCY_S + 0.68           # epochs 20..23 are complete by then
    reads = (_on_time_reads(true_t[:20], jitter[:20])
             + [(held, 1),                          # the reader got only epoch 20's bytes (a chunk split)...
                held + 0.001]                       # ...and the three behind it at once
             + _on_time_reads(true_t[24:], jitter[24:]))
    stamper, stamps, n_reads = _run(true_t, rx, reads)
    assert n_reads == 20 + 2 + 16
    assert np.all(np.diff(stamps) > 0)
    np.testing.assert_allclose(stamps - true_t, 0.004, atol=1e-6)
    assert stamper.stamps_held == 0 and stamper.receiver_clock_jumps == 0


def test_a_late_single_fix_is_not_stamped_late():
    """A read held up 0.15 s (less than the epochs' spacing) returns one epoch alone: its stamp is its true
    time plus the usual delay, not its arrival."""
    true_t, rx = _epochs(30)
    reads = _on_time_reads(true_t, np.full(30, 0.003))
    reads[12] += 0.15
    _, stamps, _ = _run(true_t, rx, reads)
    assert stamps[12] - true_t[12] == pytest.approx(0.003, abs=1e-6)
    np.testing.assert_allclose(stamps - true_t, 0.003, atol=1e-6)


def test_a_burst_at_start_up_is_stamped_back_from_its_last_epoch():
    """The first read is a backlog of five epochs (no history yet): the last arrived least delayed, so the
    earlier ones are stamped back from it by the receiver's epoch spacing, not all at the read."""
    true_t, rx = _epochs(5)
    read = true_t[-1] + LATENCY_S + 0.01
    _, stamps, n_reads = _run(true_t, rx, [read])
    assert n_reads == 1
    np.testing.assert_allclose(stamps - true_t, 0.01, atol=1e-6)


@pytest.mark.parametrize("period_s, rx0", [(WEEK_S, WEEK_S - 1.0), (DAY_S, DAY_S - 1.0)])
def test_a_receiver_time_wrap_is_unwrapped(period_s, rx0):
    """iTOW at the end of the GPS week, NMEA's UTC at midnight: the receiver time restarts at 0 and the stamps
    go on at the epochs' spacing."""
    true_t, rx = _epochs(20, rx0=rx0)
    rx = rx % period_s
    assert np.any(np.diff(rx) < 0)
    stamper, stamps, _ = _run(true_t, rx, _on_time_reads(true_t, np.full(20, 0.005)), period_s)
    np.testing.assert_allclose(stamps - true_t, 0.005, atol=1e-6)
    assert stamper.wraps == 1 and stamper.receiver_clock_jumps == 0 and stamper.stamps_held == 0


@pytest.mark.parametrize("jump_s", [-1000.0, -0.5, +3600.0])
def test_a_receiver_clock_jump_reseeds_and_is_counted(jump_s):
    """A receiver reset (its clock restarts elsewhere, back or forward): counted once, stamps never go
    backwards, and from the jump on they are again within the delay of the true times."""
    true_t, rx = _epochs(60)
    rx[30:] += jump_s
    jitter = np.where(np.arange(60) % 7 == 0, 0.002, 0.02)
    stamper, stamps, _ = _run(true_t, rx, _on_time_reads(true_t, jitter))
    assert stamper.receiver_clock_jumps == 1
    assert np.all(np.diff(stamps) > 0)
    err = stamps - true_t
    assert np.all(err >= -1e-9) and np.all(err <= 0.02 + 1e-9)
    np.testing.assert_allclose(err[35:], 0.002, atol=1e-6)    # an early (least-delayed) epoch seen since


def test_stamps_never_go_backwards_and_stay_within_the_delay_of_the_truth():
    """Random read delays (each read 0–40 ms late, one in ten held up 0.2–1.5 s, a held-up read sometimes
    getting its backlog in two pieces): stamps strictly increase, never before the true time, never after the
    epoch's own arrival, and once a 5 ms read has been seen in the window, within 5 ms of the truth."""
    rng = np.random.default_rng(7)
    true_t, rx = _epochs(600)
    reads, r = [], true_t[0]
    while r < true_t[-1] + LATENCY_S + 2.0:
        step = SPACING_S + rng.uniform(-0.02, 0.02)
        if rng.random() < 0.1:
            step += rng.uniform(0.2, 1.5)
            if rng.random() < 0.5:
                reads.append(r + step)
                step += 0.001
        r += step
        reads.append(r)
    reads.sort()
    # the arrival stamp each epoch gets: the first read at or after its bytes were complete
    arrival = np.array([reads[np.searchsorted(reads, t + LATENCY_S)] for t in true_t]) - LATENCY_S
    stamper, stamps, _ = _run(true_t, rx, reads)
    assert np.all(np.diff(stamps) > 0)
    err = stamps - true_t
    assert err.min() >= -1e-9
    assert np.all(stamps <= arrival + 1e-9)
    delay = arrival - true_t
    for k in range(len(true_t)):
        in_window = (true_t <= true_t[k]) & (true_t > true_t[k] - receiver_time.WINDOW_S)
        assert err[k] <= delay[in_window].min() + 1e-9
    assert stamper.receiver_clock_jumps == 0


def test_a_fix_without_receiver_time_keeps_its_arrival_stamp():
    stamper = ReceiverTimeStamper(DAY_S)
    got = stamper.stamp_read([_fix(10.0, None), _fix(10.2, None)])
    assert [f.t_s for f in got] == [10.0, 10.2]


def test_a_stamp_shown_late_by_a_less_delayed_fix_is_held_after_the_previous():
    """At start-up the only offset seen came from a read held up 0.7 s that got one epoch; the next read, right
    after, brings the three behind it, the last only 0.1 s late: their stamps from it would fall before the
    first's, so each is put 1 ms after the previous one and counted; the next read on time is back on truth."""
    stamper = ReceiverTimeStamper(WEEK_S)
    first = stamper.stamp_read([_fix(100.7, 1000.0)])                       # true 100.0
    burst = stamper.stamp_read([_fix(100.701, 1000.2), _fix(100.701, 1000.4), _fix(100.701, 1000.6)])
    assert [f.t_s for f in first + burst] == pytest.approx([100.7, 100.701, 100.702, 100.703], abs=1e-9)
    assert stamper.stamps_held == 3
    on_time = stamper.stamp_read([_fix(100.81, 1000.8)])[0]                 # true 100.8
    assert on_time.t_s == pytest.approx(100.81, abs=1e-9) and stamper.stamps_held == 3


def test_a_repeated_epoch_keeps_the_previous_stamp():
    """The same epoch twice (a receiver repeating it) gets the same stamp, which the validator refuses as
    repeated, rather than a new time of its own."""
    stamper = ReceiverTimeStamper(WEEK_S)
    a, b = stamper.stamp_read([_fix(100.0, 1000.0), _fix(100.05, 1000.0)])
    assert a.t_s == b.t_s == 100.0
    assert stamper.receiver_clock_jumps == 0 and stamper.stamps_held == 0


def test_the_offset_follows_a_drifting_host_clock_within_one_window():
    """The host clock runs 200 ppm fast against the receiver's for 200 s: the offset grows, and the minimum
    is retaken over the window, so a stamp is early by at most the drift over one window (and late by at
    most the delay)."""
    true_t, rx = _epochs(1000)
    host_t = true_t[0] + (true_t - true_t[0]) * (1 + 200e-6)
    stamper, stamps, _ = _run(host_t, rx, _on_time_reads(host_t, np.full(1000, 0.003)))
    err = stamps - host_t
    drift_s = 200e-6 * receiver_time.WINDOW_S
    assert err.min() >= 0.003 - drift_s - 1e-6 and err.max() <= 0.003 + 1e-6
    assert err.min() < 0.003 - 0.5 * drift_s       # the window's lag is real (the bound above is not loose)
    assert math.isfinite(stamper.offset_s)
