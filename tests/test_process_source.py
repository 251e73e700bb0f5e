"""drivers.process_source: the simulated chip read by drivers.threaded_source in a child process, samples and
counters handed over through a pipe (real time: assertions on counts, never on durations)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from ahrsd.core.sample import ImuSample, SampleFlags
from ahrsd.core import sample_block
from ahrsd.core.sample_block import SampleFlagsCache
from ahrsd.drivers.errors import BusError
from ahrsd.drivers.faults import FaultPlan
from ahrsd.drivers import process_source
from ahrsd.drivers.process_source import ProcessSource, pack, unpack
from ahrsd.drivers.source_settings import SensorSettings


def sim_cfg(**kw):
    return SensorSettings(**{"source": "sim", "reader": "process", "scenario": "static", "seed": 1,
                             "errors": "adis16405", "data_ready": "", **kw})


def test_records_cross_the_pipe_unchanged():
    s = ImuSample(12.5, np.array([0.1, -0.2, 0.3]), np.array([1.0, 2.0, -9.8]), np.array([20.0, -3.0, 41.5]),
                  24.78, 5.000424, SampleFlags.NEW_DATA | SampleFlags.GAP_BEFORE, 0x10, 123456)
    (r,) = unpack(pack([s]))
    assert (r.t_s, r.temp_c, r.supply_v, r.flags, r.diag_stat, r.counter) == \
        (s.t_s, s.temp_c, s.supply_v, s.flags, s.diag_stat, s.counter)
    for a, b in ((r.gyro_rad_s, s.gyro_rad_s), (r.accel_m_s2, s.accel_m_s2), (r.mag_ut, s.mag_ut)):
        np.testing.assert_array_equal(a, b)


def collect(src, n: int, timeout_s: float = 60.0) -> list:
    got, end = [], time.monotonic() + timeout_s
    while len(got) < n and time.monotonic() < end:
        got += src.poll()
        time.sleep(0.01)
    return got


def test_the_child_reads_the_chip_and_accounts_for_every_index():
    src = ProcessSource(sim_cfg())
    try:
        assert "reader process" in src.description and src.sample_rate_hz == pytest.approx(819.2, abs=0.01)
        got = collect(src, 2000)
    finally:
        src.close()
    got += src.undelivered                                 # read by the child after the last poll
    c = src.counters()                                     # its final counts
    assert len(got) >= 2000
    counters = [s.counter for s in got]
    assert all(b > a for a, b in zip(counters, counters[1:]))
    lost = sum(b - a - 1 for a, b in zip(counters, counters[1:]))
    gaps = [s for s in got[1:] if s.flags & SampleFlags.GAP_BEFORE]
    assert lost == 0 or gaps                               # every loss is flagged where it happened
    assert c["lost_samples_host"] == lost                  # the child's own count of the same losses
    assert c["reader_reads"] >= len(got) and c["process_samples"] == len(got) - len(src.undelivered)
    assert src.chip is not None and src.chip.stats["samples_produced"] >= len(got)


def test_a_vanished_bus_in_the_child_reaches_the_daemon():
    plan = FaultPlan(seed=3)
    plan.add("bus_error", start_sample=400)                # from 0.5 s after the first read on
    src = ProcessSource(sim_cfg(), faults=plan)
    try:
        with pytest.raises(BusError, match="gone|failed|unavailable|No such device"):
            end = time.monotonic() + 60.0
            while time.monotonic() < end:
                src.poll()
                time.sleep(0.01)
    finally:
        src.close()


def test_the_daemon_logs_once_whether_the_reader_process_got_realtime_priority(caplog):
    """The child's own log goes nowhere: it tells the daemon, which logs one line, consistent with the
    child's counter (granted or refused, whatever this machine allows)."""
    import logging

    caplog.set_level(logging.INFO, logger="ahrsd.drivers.threaded_source")
    src = ProcessSource(sim_cfg())
    try:
        collect(src, 1000)
        time.sleep(0.5)
        collect(src, 1)
    finally:
        src.close()
    lines = [r.getMessage() for r in caplog.records if "real-time priority" in r.getMessage()]
    assert len(lines) == 1 and lines[0].startswith("sensor reader process: ")
    granted = src.counters()["reader_realtime_priority"] == 1
    assert ("SCHED_FIFO 50" in lines[0]) == granted and ("NO real-time" in lines[0]) == (not granted)


class _SettableClock:
    def __init__(self):
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def _bursts(chip, clock: _SettableClock, n: int) -> list[bytes]:
    """n burst reads of the chip, each in the middle of its sample period on the chip's (settable) clock."""
    from ahrsd.drivers import registers as R

    rx = []
    for k in range(n):
        clock.t = 100.0 + (k + 0.5) / chip.sample_rate_hz
        rx.append(chip.transfer(R.BURST_COMMAND + bytes(R.BURST_DATA_BYTES), R.SPI_BURST_HZ, 0))
    return rx


def test_the_chip_computes_the_same_samples_in_its_producer_process():
    """drivers.sim_block_producer moves the simulator out of the reader's process, not what it computes: burst
    for burst across three 256-sample blocks, the same bytes as the producer thread's."""
    from ahrsd.drivers.simulated import SimulatedAdis16405

    out = {}
    for producer in ("thread", "process"):
        clock = _SettableClock()
        chip = SimulatedAdis16405("level-turns", seed=5, clock=clock, producer=producer)
        try:
            out[producer] = _bursts(chip, clock, 700)
        finally:
            chip.close()
    assert len(set(out["thread"])) > 600                    # a moving scenario: the samples differ
    assert out["process"] == out["thread"]


def test_the_hand_over_never_blocks_the_reader_on_a_full_pipe():
    """While the daemon does not read (its pipe full) the child's hand-over sends nothing and keeps what it
    took; once there is room everything goes, in order, once."""
    import multiprocessing

    from ahrsd.drivers import process_source

    def sample(k):
        return ImuSample(k * 0.001, np.zeros(3), np.zeros(3), np.zeros(3), 25.0, 5.0, SampleFlags.NEW_DATA, 0, k)

    class Source:                                            # the reader's bounded buffer
        realtime_refused = None
        chip = None                                          # a real sensor's (SensorSource.chip)

        def __init__(self):
            self.buf, self.k = [], 0

        def read(self, n):
            self.buf += [sample(self.k + i) for i in range(n)]
            self.k += n

        def poll(self):
            out, self.buf = self.buf, []
            return out

        def counters(self):
            return {}

    daemon_end, child_end = multiprocessing.Pipe()
    src = Source()
    room = [False]
    h = process_source._Handover(child_end, src, room=lambda: room[0])
    for _ in range(5):
        src.read(3)
        h.plan.latest_s = 0.0
        h.maybe_send()
    assert not daemon_end.poll(0)                            # nothing sent while the pipe had no room
    room[0] = True
    h.plan.latest_s = 0.0
    h.maybe_send()
    h.plan.latest_s = 0.0
    h.maybe_send()
    got = []
    while daemon_end.poll(0.2):
        msg = process_source.receive(daemon_end)
        if msg[0] == "samples":
            got += [s.counter for s in unpack(msg[1])]
    assert got == list(range(15))


def test_the_simulated_chip_powers_on_when_its_stream_is_open():
    """Sample 0 becomes ready when the chip can make it: a stream that takes a second to open (a producer
    process importing the simulator) costs no sample; the first read a half period later gets sample 0."""
    from ahrsd.drivers import registers as R
    from ahrsd.drivers.simulated import SimulatedAdis16405
    from ahrsd.simulation import open_stream

    clock = _SettableClock()

    def slow_to_open(rate_hz, start_s):
        clock.t += 1.0
        return open_stream("static", rate_hz=rate_hz, seed=2, errors="adis16405", start_s=start_s)

    chip = SimulatedAdis16405(slow_to_open, clock=clock)
    try:
        clock.t += 0.5 / chip.sample_rate_hz
        chip.transfer(R.BURST_COMMAND + bytes(R.BURST_DATA_BYTES), R.SPI_BURST_HZ, 0)
        assert chip.sample_index == 0 and chip.stats["samples_lost"] == 0
    finally:
        chip.close()


def _wait_ahead(stream, n: int, timeout_s: float = 120.0) -> None:
    end = time.monotonic() + timeout_s
    while stream.blocks_ahead() < n and time.monotonic() < end:
        time.sleep(0.05)
    assert stream.blocks_ahead() == n


def test_a_starved_producer_costs_no_block_while_its_ring_lasts():
    """The producer computes ahead into shared memory: stopped (a producer starved of CPU), the chip still
    takes every block it had made without waiting — 24 blocks, 7.5 s of samples at 819.2 SPS — and its
    blocks are the stream's own."""
    import os
    import signal
    import threading

    from ahrsd.drivers.sim_block_producer import SLOTS, ProducedStream
    from ahrsd.simulation import open_stream

    assert SLOTS >= 24
    stream = ProducedStream("level-turns", 819.2, 4, "adis16405", 0.0, 256)
    blocks: list = []

    def take():
        for _ in range(24):
            blocks.append(stream.next_block(256))

    try:
        _wait_ahead(stream, SLOTS)
        os.kill(stream.pid, signal.SIGSTOP)
        taker = threading.Thread(target=take, daemon=True)
        taker.start()
        taker.join(30.0)                                   # a chip that waits on its producer waits for good
        taken_while_stopped = len(blocks)
    finally:
        os.kill(stream.pid, signal.SIGCONT)
        stream.close()                                     # (ends a taker still waiting: the producer is gone)
    assert taken_while_stopped == 24
    here = open_stream("level-turns", rate_hz=819.2, seed=4, errors="adis16405", start_s=0.0)
    for blk in blocks:
        want = here.next_block(256)
        np.testing.assert_array_equal(blk.t_s, want.t_s)
        np.testing.assert_array_equal(blk.gyro_rad_s, want.gyro_rad_s)
        np.testing.assert_array_equal(blk.mag_ut, want.mag_ut)
        np.testing.assert_array_equal(blk.truth_q_wxyz, want.truth_q_wxyz)


def test_a_rate_change_restarts_the_stream_in_the_same_producer_process():
    """SMPL_PRD written ([sensor] rate_hz): the producer process that imported the simulator computes the new
    rate's stream (a new process would import it again), and the chip takes the new stream's blocks only, not
    the old rate's blocks the ring still held: the stream's own, from the new start time."""
    from ahrsd.drivers import registers as R
    from ahrsd.drivers.sim_block_producer import SLOTS, ProducedStream
    from ahrsd.simulation import open_stream

    rate_hz = R.sample_rate_hz(0x07)                       # 1638.404 / 8 = 204.8505 SPS
    stream = ProducedStream("level-turns", 819.2, 4, "adis16405", 0.0, 256)
    try:
        stream.next_block(256)
        _wait_ahead(stream, SLOTS)                         # old blocks made and announced: to be discarded
        pid = stream.pid
        stream.restart(rate_hz, 2.5)
        blocks = [stream.next_block(256) for _ in range(3)]
        assert stream.pid == pid and stream._proc.poll() is None
    finally:
        stream.close()
    here = open_stream("level-turns", rate_hz=rate_hz, seed=4, errors="adis16405", start_s=2.5)
    for blk in blocks:
        want = here.next_block(256)
        np.testing.assert_array_equal(blk.t_s, want.t_s)
        np.testing.assert_array_equal(blk.gyro_rad_s, want.gyro_rad_s)
        np.testing.assert_array_equal(blk.truth_q_wxyz, want.truth_q_wxyz)


def test_the_chip_restarts_its_producer_at_the_written_rate():
    """The simulated chip's SMPL_PRD write (the driver's configure) reaches its producer process: the bursts
    after it are the thread producer's, byte for byte, on the new rate's grid."""
    from ahrsd.drivers import registers as R
    from ahrsd.drivers.simulated import SimulatedAdis16405

    out, pids = {}, []
    for producer in ("thread", "process"):
        clock = _SettableClock()
        chip = SimulatedAdis16405("level-turns", seed=5, clock=clock, producer=producer)
        try:
            pids += chip.helper_pids()
            for frame in R.write_frames(R.SMPL_PRD, 0x07):
                chip.transfer(frame, R.SPI_SLOW_HZ, 0)
            pids += chip.helper_pids()
            assert chip.sample_rate_hz == R.sample_rate_hz(0x07)
            out[producer] = _bursts(chip, clock, 300)
        finally:
            chip.close()
    assert len(pids) == 2 and pids[0] == pids[1]           # the process producer's, before and after
    assert len(set(out["thread"])) > 250
    assert out["process"] == out["thread"]


def test_a_realtime_reader_gives_its_chips_producer_its_own_priority():
    """Nothing a SCHED_FIFO reader waits on may run below it: the reader thread that got real-time priority
    gives the simulated chip's block producer the same (skipped where this machine refuses SCHED_FIFO)."""
    import os

    from ahrsd.drivers.source import open_source
    from ahrsd.drivers.threaded_source import FIFO_PRIORITY

    src = open_source(sim_cfg(reader="thread"))
    try:
        collect(src, 200)
        c = src.counters()
        if not c["reader_realtime_priority"]:
            pytest.skip("SCHED_FIFO refused here: the reader runs at normal priority, like its producer")
        (pid,) = src.chip.helper_pids()
        assert c["reader_helpers_realtime"] == 1
        assert os.sched_getscheduler(pid) == os.SCHED_FIFO
        assert os.sched_getparam(pid).sched_priority == FIFO_PRIORITY
    finally:
        src.close()


def test_the_hand_over_sends_one_bounded_message_a_tick_and_never_blocks_a_real_pipe():
    """A daemon that does not read: on a real socket pair the hand-over fills the pipe and then waits with
    its backlog (every tick returns: the reader reads on), one samples message a tick at most; once the daemon
    reads, all 20 000 samples arrive, in order, once."""
    import multiprocessing
    import threading

    from ahrsd.drivers import process_source

    class Reader:                                            # the reader's buffer, 20 000 samples read
        realtime_refused = None
        chip = None                                          # a real sensor's (SensorSource.chip)

        def __init__(self):
            self.buf = [ImuSample(k * 0.001, np.zeros(3), np.zeros(3), np.zeros(3), 25.0, 5.0,
                                  SampleFlags.NEW_DATA, 0, k) for k in range(20000)]

        def poll(self):
            out, self.buf = self.buf, []
            return out

        def counters(self):
            return {}

    class CountingEnd:                                       # the child's end, counting messages per tick
        def __init__(self, conn):
            self.conn, self.samples_messages = conn, 0

        def fileno(self):
            return self.conn.fileno()

        def send(self, msg):
            self.conn.send(msg)

        def send_bytes(self, data):                          # a samples message (process_source.send_samples)
            self.samples_messages += 1
            self.conn.send_bytes(data)

    daemon_end, child_end = multiprocessing.Pipe()
    end = CountingEnd(child_end)
    h = process_source._Handover(end, Reader())
    per_tick: list[int] = []

    def ticks(n):
        for _ in range(n):
            before = end.samples_messages
            h.plan.latest_s = 0.0
            h.maybe_send()
            per_tick.append(end.samples_messages - before)

    ticker = threading.Thread(target=ticks, args=(300,), daemon=True)
    ticker.start()
    ticker.join(60.0)
    assert not ticker.is_alive(), "the hand-over blocked on a full pipe"
    assert max(per_tick) == 1
    assert 0 < sum(per_tick) < 20000 / h.chunk_samples and h.pending     # the pipe filled: the rest waits
    got: list[int] = []
    for _ in range(10000):
        while daemon_end.poll(0):
            msg = process_source.receive(daemon_end)
            if msg[0] == "samples":
                got += [s.counter for s in unpack(msg[1])]
        if len(got) == 20000:
            break
        ticks(1)
    assert got == list(range(20000))


def test_a_cached_flags_value_is_not_made_again_not_even_none():
    """A flags value seen once is taken from the cache after, SampleFlags.NONE (falsy) too; unpack goes through
    the process's cache (its `made` count moves once per value it has not seen)."""
    cache = SampleFlagsCache()
    values = [int(SampleFlags.NONE), int(SampleFlags.NEW_DATA)] * 5 + [int(SampleFlags.NEW_DATA | SampleFlags.STALE)]
    got = [cache[v] for v in values]
    assert got == [SampleFlags(v) for v in values] and all(type(f) is SampleFlags for f in got)
    assert cache.made == 3                                       # NONE, NEW_DATA, NEW_DATA|STALE: once each

    flags = [SampleFlags.NONE, SampleFlags.NEW_DATA] * 5 + [SampleFlags.NEW_DATA | SampleFlags.STALE]
    samples = [ImuSample(k / 819.2, np.zeros(3), np.zeros(3), np.zeros(3), 24.0, 5.0, f, 0, k)
               for k, f in enumerate(flags)]
    made_before = sample_block.SAMPLE_FLAGS.made
    for f in set(flags):
        sample_block.SAMPLE_FLAGS.pop(int(f), None)              # as if not seen yet in this process
    got = unpack(pack(samples)) + unpack(pack(samples))
    assert [r.flags for r in got] == flags + flags
    assert sample_block.SAMPLE_FLAGS.made == made_before + 3     # each value made once, then found


def test_blocks_unpacked_together_keep_every_sample_its_own_flags_and_order():
    """The daemon unpacks every block of a poll in one go, flags through a cache: each sample keeps its values."""
    flags = [SampleFlags.NEW_DATA, SampleFlags.NONE, SampleFlags.NEW_DATA | SampleFlags.GAP_BEFORE,
             SampleFlags.NEW_DATA | SampleFlags.ALARM | SampleFlags.GYRO_INVALID, SampleFlags.NEW_DATA,
             SampleFlags.NEW_DATA | SampleFlags.GAP_BEFORE]
    samples = [ImuSample(100.0 + k / 819.2, np.array([k, -k, 0.5 * k]), np.array([0.1, -9.8, k]),
                         np.array([20.0 + k, -3.0, 41.5]), 24.0 + k, 5.0, f, 0x10 * k, 1000 + 2 * k)
               for k, f in enumerate(flags)]
    got = unpack(pack(samples[:2]) + pack(samples[2:5]) + pack(samples[5:]))
    assert [(r.t_s, r.temp_c, r.supply_v, r.flags, r.diag_stat, r.counter) for r in got] == \
        [(s.t_s, s.temp_c, s.supply_v, s.flags, s.diag_stat, s.counter) for s in samples]
    assert all(type(r.flags) is SampleFlags for r in got)
    for r, s in zip(got, samples):
        for a, b in ((r.gyro_rad_s, s.gyro_rad_s), (r.accel_m_s2, s.accel_m_s2), (r.mag_ut, s.mag_ut)):
            np.testing.assert_array_equal(a, b)


def test_the_hand_over_drains_a_backlog_every_handover_s_and_else_waits_handover_max_s(monkeypatch):
    """The reader process's next hand-over (drivers.handover_plan's latest_s), by worked times on a stepped clock: a
    tick that leaves samples pending (more than one message's chunk) comes again HANDOVER_S later, one that sent
    them all HANDOVER_MAX_S later."""
    import multiprocessing
    from types import SimpleNamespace

    read: list = []
    src = SimpleNamespace(realtime_refused=None, counters=dict, poll=lambda: [read.pop(0) for _ in list(read)])
    now = [100.0]
    monkeypatch.setattr(process_source, "time", SimpleNamespace(monotonic=lambda: now[0]))
    daemon_end, child_end = multiprocessing.Pipe()
    h = process_source._Handover(child_end, src, room=lambda: True)
    h.next_counters = 1e9                                   # no counters message in the way
    read[:] = [ImuSample(t_s=k, gyro_rad_s=np.zeros(3), accel_m_s2=np.zeros(3), mag_ut=np.zeros(3), temp_c=25.0,
                         supply_v=5.0, flags=SampleFlags.NEW_DATA, diag_stat=0, counter=k)
               for k in range(h.chunk_samples + 1)]
    h.maybe_send()
    assert len(h.pending) == 1 and h.plan.latest_s == pytest.approx(100.0 + process_source.HANDOVER_S)
    now[0] = 100.0 + process_source.HANDOVER_S
    h.maybe_send()
    assert not h.pending and h.plan.latest_s == pytest.approx(now[0] + process_source.HANDOVER_MAX_S)
    daemon_end.close()
    child_end.close()
