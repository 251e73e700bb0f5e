"""Sample accounting against the simulated chip's ground truth (zero unexplained lost samples).

The daemon has no sample counter to read (the ADIS16405 has none): the per-sample reader indexes each fresh
read from the host clock (drivers.sample_timer.SampleTimer). Here the reader, SampleReader.step, runs on a fake
clock against the byte-level chip, with the two things a loaded machine adds: wakes that come late, and time
passing between the wake and the SPI transfer (the process preempted before the ioctl). The chip's own index
at each burst is the ground truth (the daemon never sees it).

Invariant checked at every read: offset = (daemon index − first daemon index) − (chip index − first chip
index) never goes below 0 — a negative offset is a real lost sample the daemon did not count. A positive
offset is a phantom loss; it must stay within what the timer reported as ambiguous (`ambiguous_samples`).
Before the fix the wake time indexed the read, and reads after a rejected frame or a burst-bug register read
(both clear ND on the chip) were taken as proof that the next sample was not ready: the lock slid a whole
period and the offset went negative (16 of 22 943 samples in the CI soak).
"""

from __future__ import annotations

import random
from collections import Counter

import numpy as np
import pytest

from ahrsd.cli.fault_schedule import build_plan, parse_schedule
from ahrsd.core.sample import SampleFlags
from ahrsd.drivers import registers as R
from ahrsd.drivers.chip_source import ADIS16405_RATE_HZ
from ahrsd.drivers.ground_truth import GroundTruthSource
from ahrsd.drivers.reconnecting import ReconnectingSource
from ahrsd.drivers.sample_timer import SampleTimer
from ahrsd.drivers.simulated import SimulatedAdis16405
from ahrsd.drivers.source import open_chip_driver, start_chip_source
from ahrsd.drivers.source_recorder import SourceRecorder
from reader_rig import ReaderRig
from sim_streams import FixedStream
from support.chip_bus import SimulatedChipBus
from support.stepped_clock import ManualClock

CI_FAULTS = ("alarm@3-3.5:bits=SUPPLY_LOW;garbage@4-6:p=0.02;bus_error@7-8;stall@11-11.5;"
             "stuck_axis@13-15:axis=mag_x;short_read@16-17:p=0.01;burst_bug@18-20")   # bench/soak.py CI_FAULTS


class PreemptedBus(SimulatedChipBus):
    """The chip behind a bus whose transfers start `delay(rng)` after they are asked for; records the chip's
    index at every burst (the ground truth of what the burst returned)."""

    def __init__(self, chip, clock, rng, delay):
        super().__init__(chip)
        self.clock, self.rng, self.delay = clock, rng, delay
        self.burst_index = -1

    def transfer(self, tx, speed_hz, delay_us=0):
        self.clock.t += self.delay(self.rng)
        rx = self.chip.transfer(tx, speed_hz, delay_us)
        if tx[0] == R.GLOB_CMD and tx[1] == 0:
            self.burst_index = self.chip.sample_index
        self.clock.t += len(tx) * 8.0 / speed_hz + 10e-6
        return rx

    def close(self):
        pass


def late_wakes(rng):
    """30 % of the wakes late, exponentially, mean 0.3 ms (a loaded 2-core machine)."""
    return rng.expovariate(1 / 300e-6) if rng.random() < 0.3 else 0.0


def run_reader(seconds, seed, faults="", late=late_wakes, delay=lambda rng: rng.uniform(0.0, 200e-6),
               stream=None):
    """The daemon's reader (SampleReader.step) on a fake clock against the chip; returns per-class offset
    changes and the totals."""
    rng = random.Random(seed)
    clock = ManualClock(1000.0)
    plan = build_plan(parse_schedule(faults), ADIS16405_RATE_HZ, seed=seed) if faults else None
    chip = SimulatedAdis16405(stream or FixedStream(noise_std=(1e-3, 1e-2, 0.1), seed=seed), clock=clock,
                              faults=plan)
    bus = PreemptedBus(chip, clock, rng, delay)
    src = GroundTruthSource(ReconnectingSource(lambda: bus, open_chip_driver, "test chip", clock=clock,
                                               reopen_same_bus=True), chip, bus)
    src.start()
    seen = {"first": None, "prev": None, "min_offset": 0, "offset": 0, "samples": 0, "lost": 0,
            "errors": 0, "stale": 0}
    changes = Counter()

    def on_sample(s):
        true = bus.burst_index                             # the chip's index at the burst just read
        since = set(rig.errors[seen["errors"]:])
        stale = src.counters()["stale_reads"]
        if stale > seen["stale"]:
            since.add("stale")
        seen["errors"], seen["stale"] = len(rig.errors), stale
        if seen["first"] is None:
            seen["first"] = (true, s.counter)
        else:
            seen["samples"] += 1
            seen["lost"] += s.counter - seen["prev"] - 1
            first = seen["first"]
            new_offset = (s.counter - first[1]) - (true - first[0])
            if new_offset != seen["offset"]:
                changes["+".join(sorted(since)) or "consecutive"] += new_offset - seen["offset"]
            seen["offset"] = new_offset
            seen["min_offset"] = min(seen["min_offset"], new_offset)
        seen["prev"] = s.counter
        clock.t += 30e-6                                   # processing

    rig = ReaderRig(src, clock, on_sample)
    try:
        rig.run_for(seconds, lateness=lambda: late(rng))
    finally:
        rig.close()
    return dict(min_offset=seen["min_offset"], offset=seen["offset"], changes=changes,
                samples=seen["samples"] + 1, lost=seen["lost"], chip_total=src.last_chip_index - seen["first"][0] + 1,
                ambiguous=src.timer.ambiguous_samples, stats=src.stats, chip=chip,
                pipeline_lost=rig.pipeline.counters.lost_samples)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_late_wakes_and_delayed_transfers_never_hide_a_lost_sample(seed):
    r = run_reader(10.0, seed)
    assert r["min_offset"] >= 0, r["changes"]
    assert r["lost"] > 50                          # the load really lost samples
    phantom = r["samples"] + r["lost"] - r["chip_total"]
    assert phantom == r["offset"] >= 0
    assert phantom <= r["ambiguous"]


def test_transfer_delayed_past_the_next_ready_time_is_indexed_by_the_transfer():
    """Wakes on time, but every transfer starts 0–0.4 ms after the wake: with the wake time as the read time
    the index came out one low whenever the next sample became ready in between."""
    r = run_reader(10.0, 3, late=lambda rng: 0.0, delay=lambda rng: rng.uniform(0.0, 400e-6))
    assert r["min_offset"] >= 0, r["changes"]
    assert r["offset"] <= r["ambiguous"]


def test_burst_bug_register_reads_consume_samples_without_sliding_the_lock():
    """A negative X rate makes every burst carry the burst bug; the driver then reads XGYRO_OUT, which clears
    ND: a sample that became ready meanwhile is consumed unseen, and the next stale read is no evidence."""
    stream = FixedStream(gyro_rad_s=(-0.2, 0.0, 0.0), noise_std=(1e-3, 1e-2, 0.1), seed=5)
    r = run_reader(8.0, 5, faults="burst_bug@0-8", stream=stream)
    assert r["chip"].faults.injected["burst_bug"] > 1000
    assert r["min_offset"] >= 0, r["changes"]
    assert r["offset"] <= r["ambiguous"]


def test_rejected_frames_consume_samples_without_sliding_the_lock():
    r = run_reader(8.0, 6, faults="garbage@0-8:p=0.05")
    assert r["stats"]["lost_in_fault_windows"] > 0
    assert r["min_offset"] >= 0, r["changes"]
    assert r["offset"] <= r["ambiguous"]


@pytest.mark.parametrize("seed", [0])     # one seed: it fails on every break seed 1 did (docs/testing.md)
def test_ci_fault_schedule_under_load_accounts_for_every_sample(seed):
    """bus loss + reconnect, stall, garbage, short reads, alarms, burst bug: the span of the outage and of the
    stall is counted from the elapsed time, never less than the chip produced."""
    r = run_reader(21.0, seed, faults=CI_FAULTS)
    assert r["stats"]["reopens"] >= 1
    assert r["min_offset"] >= 0, r["changes"]
    assert r["offset"] <= r["ambiguous"]


def test_sample_timer_takes_the_largest_index_the_bracket_allows_and_counts_the_ambiguity():
    P = 1.0 / ADIS16405_RATE_HZ
    t = SampleTimer(P)
    t.fresh(10.0)                                   # sample 0 read at 10.0: φ in (10 − P, 10]
    t.stale(10.0 + 0.9 * P)                         # sample 1 not ready at 10 + 0.9 P: φ > 10 − 0.1 P
    _, k, lost = t.fresh(10.0 + 1.05 * P)           # unambiguous: sample 1
    assert (k, lost) == (1, 0) and t.ambiguous_reads == 0
    # a transfer that started before and ended after the time sample 3 may have become ready
    lo, hi = t.lo, t.hi
    start = hi + 2.9 * P
    _, k, lost = t.fresh(start, start + 0.3 * P)
    assert k == 3 and lost == 1                     # the largest index: a loss is never hidden
    assert t.ambiguous_reads == 1 and t.ambiguous_samples == 1
    assert lo < hi


def test_stale_read_after_a_consumed_sample_is_evidence_only_for_the_one_after():
    P = 1.0 / ADIS16405_RATE_HZ
    t = SampleTimer(P)
    t.fresh(10.0)
    t.stale(10.0 + 0.95 * P)
    t.fresh(10.0 + 1.02 * P)
    lo = t.lo
    t.may_have_consumed(10.0 + 2.2 * P)             # that read went on with register reads until 2.2 P
    t.stale(10.0 + 2.5 * P)                         # sample 2 may already be gone: no bound from it
    assert t.lo <= lo                               # "sample 3 not ready" adds nothing; "sample 2" would
    t2 = SampleTimer(P)                             # (the same reads without the hint: lo jumps to 10 + 0.5 P)
    t2.fresh(10.0)
    t2.stale(10.0 + 0.95 * P)
    t2.fresh(10.0 + 1.02 * P)
    t2.stale(10.0 + 2.5 * P)
    assert t2.lo > 10.0 + 0.4 * P
    _, k, _ = t.fresh(10.0 + 3.02 * P)
    assert k == 3 and t._consumed_upto == -1


@pytest.mark.parametrize("pacing", ["host timer", "data-ready edges", "data-ready edges, waited for"])
def test_a_sample_ready_during_the_burst_bug_check_read_is_not_lost(pacing):
    """#31 (bench/soak.py: 209 losses in a 20 s burst_bug window): every burst carries the X-gyro burst bug, so the
    driver reads XGYRO_OUT after it. Every fourth read comes late, 0.1 ms before the next sample is ready, so that
    sample becomes ready between the burst and the register read; the read takes its ND. Stepped clock (the
    wire time of each transfer), ground truth = the chip's index at each burst: every sample the chip produced
    must come out once, indexed without doubt. Paced by the host timer (SampleTimer) or by data-ready edges
    (DataReadyTimer: read at its next_read_time as the event-loop reader does, or after waiting on the line).
    (Broken by forgetting that the register read took ND: 50 of 200 samples lost with each pacing; by not
    telling the timer that a newer sample was ready: 50 lost with the edges (25 waited for), and with the host
    timer 1 lost and every later index one high; by still reading XGYRO_OUT after a stale burst: a phantom loss
    counted with the host timer.)"""
    from ahrsd.drivers.adis16405 import Adis16405
    from ahrsd.drivers.chip_source import ChipSource
    from ahrsd.drivers.data_ready import DataReadyTimer
    from ahrsd.drivers.simulated import SimulatedDataReadyLine

    period = 1.0 / ADIS16405_RATE_HZ
    clock = ManualClock(1000.0)
    stream = FixedStream(gyro_rad_s=(-0.2, 0.0, 0.0), noise_std=(1e-3, 1e-2, 0.1), seed=7)
    chip = SimulatedAdis16405(stream, clock=clock, faults=build_plan(parse_schedule("burst_bug@0-100"),
                                                                     ADIS16405_RATE_HZ))
    bus = PreemptedBus(chip, clock, random.Random(0), lambda rng: 0.0)
    edges = pacing.startswith("data-ready")
    driver = Adis16405(bus, data_ready=edges)
    driver.start(self_test=False)
    timer = None
    if edges:
        timer = DataReadyTimer(SimulatedDataReadyLine(chip, host_clock=clock,
                                                      sleep_until=lambda t: setattr(clock, "t", max(clock.t, t))),
                               period)
    src = ChipSource(driver, bus, "test chip", clock=clock, timer=timer)

    def read(due):
        if pacing.endswith("waited for"):
            timer.wait(1.0)
        clock.t = max(clock.t, due)
        s = src.read_one(clock.t)
        return None if s is None else (bus.burst_index, s.counter)

    for _ in range(50):                                  # lock the reader's phase on the chip
        read(src.next_read_time())
    got = []
    ambiguous_at_lock = src.timer.ambiguous_reads if not edges else 0
    for i in range(201):                                 # ends on an on-time read
        due = src.next_read_time()
        if i % 4 == 3:                                   # late: 0.1 ms before the next sample is ready
            due = chip.ready_clock_time(chip.first_index_after(due)) - 100e-6
        r = read(due)
        if r is not None:
            got.append(r)
    indices = [g[0] for g in got]
    produced = range(indices[0], chip.sample_index + 1)
    assert chip.faults.injected["burst_bug"] > 150
    assert driver.counters["nd_taken_by_check"] >= 45            # (nearly) every late read's check read took a new ND
    outcome = {"lost": len(set(produced) - set(indices)), "delivered twice": len(indices) - len(set(indices)),
               "index offsets": len({chip_i - k for chip_i, k in got}), "counted lost": src.lost_samples,
               "ambiguous reads": 0 if edges else src.timer.ambiguous_reads - ambiguous_at_lock}
    assert outcome == {"lost": 0, "delivered twice": 0, "index offsets": 1, "counted lost": 0, "ambiguous reads": 0}


def loaded_wakes(rng):
    """A machine at load ~10 on two cores: 40 % of the wakes late, 1 % of them by up to 4 periods."""
    x = rng.random()
    if x < 0.01:
        return rng.uniform(0.0, 5e-3)
    return rng.expovariate(1 / 400e-6) if x < 0.4 else 0.0


@pytest.mark.parametrize("seed", [0])     # one seed: it fails on every break seed 1 did (docs/testing.md)
def test_every_sample_has_the_chips_own_index_under_load(seed):
    """Issue 30 (a real-time `record --sim` at load ~10 had ~2 % of rows one sample off the chip's index): a
    burst that may have straddled a data-ready is indexed by the chip's ND (a register read after it), not by
    the largest index the host clock allows. Every sample's index is the chip's (offset from the first row
    never changes), and the samples counted lost are exactly those the chip produced unread."""
    r = run_reader(10.0, seed, late=loaded_wakes)
    assert not r["changes"] and r["offset"] == 0, r["changes"]
    assert r["lost"] > 50                          # the load really lost samples
    assert r["samples"] + r["lost"] == r["chip_total"]


class _Rows:
    """A recording writer that keeps each row's counter and flags beside the chip's index at its burst."""

    def __init__(self, bus):
        self.bus, self.rows = bus, []

    def write(self, sample, truth_q_wxyz=None):
        self.rows.append((sample.counter, self.bus.burst_index, int(sample.flags)))


def test_a_real_time_recordings_counter_is_the_chips_index():
    """`ahrsd record --sim --realtime`'s loop (drivers.source_recorder, the same ChipSource and timer as the
    daemon) on a stepped clock at load: each row's counter is the chip's sample index (against the first row),
    and GAP_BEFORE marks exactly the rows after samples the chip produced unread."""
    rng = random.Random(7)
    clock = ManualClock(1000.0)
    chip = SimulatedAdis16405(FixedStream(noise_std=(1e-3, 1e-2, 0.1), seed=7), clock=clock)
    bus = PreemptedBus(chip, clock, rng, lambda rng: rng.uniform(0.0, 200e-6))
    source = start_chip_source(bus, "test chip", clock=clock, self_test=False)
    rows = _Rows(bus)

    def late_sleep(seconds):
        clock.t += seconds + loaded_wakes(rng)

    SourceRecorder(source, rows, paced=True, clock=clock, sleep=late_sleep).run(8192)
    counter, chip_index, flags = (np.array(c) for c in zip(*rows.rows))
    assert np.count_nonzero(np.diff(chip_index) > 1) > 50          # the load really lost samples
    assert np.array_equal(counter - counter[0], chip_index - chip_index[0])
    gap = (flags[1:] & int(SampleFlags.GAP_BEFORE)) != 0
    assert np.array_equal(gap, np.diff(chip_index) > 1)
