"""The reader process hands its block over when the daemon's next output falls due (drivers.process_source
`_Handover`, told by daemon.sample_reader through `hand_over_by`), or at the latest HANDOVER_MAX_S after the
last time: a wake of the event loop per output due, each output sent with the first sample read at or after
its deadline, every output's rate exact.

The child's hand-over logic (`_Handover`, its packing) and the daemon's reader (SampleReader on a real asyncio
loop, its `add_reader`, stand-in tick and output schedule: daemon.outputs.OutputSchedule) run together on a
virtual clock (tests/support/virtual_time_loop.py): the chip is read every 1/819.2 s of loop time, a block
reaches the daemon PIPE_DELAY_S after it was sent (longer than a sample period: the child reads again before
the daemon has told it the next deadline). Expected counts are computed from the rates, not by the code."""

from __future__ import annotations

import asyncio
import math
import os
from types import SimpleNamespace

import pytest

from ahrsd.calibration.models import Calibration
from ahrsd.core.estimate import EstimateFlags
from ahrsd.core.sample import make_sample
from ahrsd.daemon.counters import ServiceCounters
from ahrsd.daemon.health import Health
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.outputs import OutputSchedule
from ahrsd.daemon.pipeline import Pipeline
from ahrsd.daemon.sample_reader import ReaderOutputs, SampleListeners, SampleReader
from ahrsd.drivers import process_source
from ahrsd.drivers.source_interface import LiveSource
from support.virtual_time_loop import VirtualTimeLoop

RATE_HZ = 819.2
PERIOD_S = 1.0 / RATE_HZ
PIPE_DELAY_S = 0.002
RUN_S = 10.0
ATT, VPE, HIGHRES, SYS = (mavlink.MAVLINK_MSG_ID_ATTITUDE, mavlink.MAVLINK_MSG_ID_VISION_POSITION_ESTIMATE,
                          mavlink.MAVLINK_MSG_ID_HIGHRES_IMU, mavlink.MAVLINK_MSG_ID_SYS_STATUS)
GCS_RATES_HZ = {ATT: 50.0, VPE: 30.0, HIGHRES: 10.0, SYS: 1.0}
AUTOPILOT_RATES_HZ = {VPE: 30.0, SYS: 1.0}


class _Est:
    flags = EstimateFlags.NONE


class _StubEstimator:
    def update(self, sample):
        return _Est()


class _ChildSource:
    """The child's reader: the samples read since its last poll."""

    realtime_refused = None
    chip = None

    def __init__(self):
        self.buf = []

    def poll(self):
        out, self.buf = self.buf, []
        return out

    def counters(self):
        return {}


class _World:
    """The chip, the child's hand-over and the pipe, as events of the virtual loop; the daemon's end of the pipe
    as the SampleReader's source."""

    def __init__(self, loop: VirtualTimeLoop, stop_reads_at: float = math.inf):
        self.loop = loop
        self.t0 = loop.time()
        self.stop_reads_at = self.t0 + stop_reads_at
        self.wanted = math.inf                    # the shared value: the daemon's next output deadline
        self.read_fd, self.write_fd = os.pipe()
        os.set_blocking(self.read_fd, False)
        self.arrived: list[bytes] = []
        self.child = _ChildSource()
        self.handover = process_source._Handover(self, self.child, room=lambda: True, wanted=lambda: self.wanted)
        self.sent_at: list[float] = []            # loop time of every samples message
        self.k = 0

    # the child's end of the pipe (what _Handover sends through)
    def fileno(self):
        return self.write_fd

    def send(self, msg):
        pass                                      # counters: not the subject here

    def send_bytes(self, data):
        self.sent_at.append(self.loop.time())
        self.loop.call_at(self.loop.time() + PIPE_DELAY_S, self._arrive, data)

    def _arrive(self, data):
        self.arrived.append(bytes(data[1:]))      # behind the samples tag
        os.write(self.write_fd, b"x")

    def read(self):
        t = self.loop.time()
        if t >= self.stop_reads_at:
            return
        self.child.buf.append(make_sample(t, [0, 0, 0], [0, 0, -9.8], [20, 0, 40], counter=self.k))
        self.handover.maybe_send()                # the reader thread's after_read
        self.k += 1
        self.loop.call_at(self.t0 + self.k * PERIOD_S, self.read)

    def close(self):
        os.close(self.read_fd)
        os.close(self.write_fd)


class _DaemonEnd(LiveSource):
    sample_rate_hz = RATE_HZ
    per_sample = False
    handover_max_s = process_source.HANDOVER_MAX_S

    def __init__(self, world: _World):
        self.world = world
        self.ready_fd = world.read_fd
        self.blocks: list[tuple[float, int, float]] = []     # (loop time taken, samples, newest sample's time)

    def hand_over_by(self, t: float) -> None:
        self.world.wanted = t

    def poll(self):
        try:
            os.read(self.ready_fd, 4096)
        except BlockingIOError:
            pass
        data, self.world.arrived = self.world.arrived, []
        if not data:
            return []
        block = process_source.unpack_block(b"".join(data))
        self.blocks.append((self.world.loop.time(), len(block), block.t_s[-1]))
        return block

    def counters(self):
        return {}

    def close(self):
        pass


def _run(monkeypatch, rates_hz: dict[int, float], stop_reads_at: float = math.inf):
    """RUN_S of loop time; returns (world, source, reader, sent: [(message id, loop time, newest sample time)],
    the schedule's first deadline)."""
    loop = VirtualTimeLoop()
    monkeypatch.setattr(process_source, "time", SimpleNamespace(monotonic=loop.time))
    world = _World(loop, stop_reads_at)
    source = _DaemonEnd(world)
    schedule = OutputSchedule(rates_hz)
    sent: list[tuple[int, float, float | None]] = []
    seen: list[int] = []
    reader_box = []

    def publish(now):
        for mid in schedule.due(now):
            last = reader_box[0].pipeline.last_sample
            sent.append((mid, now, None if last is None else last.t_s))

    reader = SampleReader(source, Pipeline(_StubEstimator(), Calibration.identity()), Health(stale_timeout_s=0.1),
                          ServiceCounters(), SampleListeners(),
                          ReaderOutputs(publish=publish, statustext=lambda sev, text: None,
                                        heading_reset=lambda: None, ready=lambda: None,
                                        next_due=lambda: schedule.next_due),
                          poll_hz=200.0)
    reader_box.append(reader)
    reader.listeners.add(lambda s, e: seen.append(s.counter))

    async def main():
        task = loop.create_task(reader.run(loop))
        world.read()                                   # the chip's first sample, at the loop's start
        await asyncio.sleep(RUN_S - 1e-6)
        task.cancel()
        try:
            await task
        except BaseException:  # noqa: BLE001 - the cancellation
            pass

    try:
        loop.run_until_complete(main())
    finally:
        loop.close()
        world.close()
    assert seen == list(range(len(seen))) and len(seen) >= (min(stop_reads_at, RUN_S) - 0.1) * RATE_HZ
    return world, source, reader, sent, sent[0][1]


def _deadlines(rate_hz: float, first: float, end: float) -> list[float]:
    n = math.ceil((end - first) * rate_hz - 1e-9)
    return [first + j / rate_hz for j in range(n)]


@pytest.mark.parametrize("rates_hz", [GCS_RATES_HZ, AUTOPILOT_RATES_HZ], ids=["gcs", "autopilot"])
def test_each_output_goes_out_at_its_rate_with_the_first_sample_read_at_its_deadline(monkeypatch, rates_hz):
    world, source, reader, sent, first = _run(monkeypatch, rates_hz)
    end = world.t0 + RUN_S
    for mid, hz in rates_hz.items():
        times = [t for m, t, _ in sent if m == mid]
        newest = [ts for m, _, ts in sent if m == mid]
        due = _deadlines(hz, first, end - PIPE_DELAY_S - PERIOD_S)       # every deadline whose block came in time
        assert len(times) in (len(due), len(due) + 1), (mid, len(times), len(due))
        # after the first block: the output went out with the first sample read at or after its deadline
        for d, ts in list(zip(due, newest))[1:]:
            assert d - 1e-9 <= ts < d + PERIOD_S + 1e-9, (mid, d, ts)


@pytest.mark.parametrize("rates_hz", [GCS_RATES_HZ, AUTOPILOT_RATES_HZ], ids=["gcs", "autopilot"])
def test_one_wake_per_output_deadline_and_one_when_none_came_for_handover_max_s(monkeypatch, rates_hz):
    """Each block ends with the first read after the next deadline (the child does not hand over again for a
    deadline it served, though it reads again before the daemon told it the next one), or HANDOVER_MAX_S after
    the last block if no deadline comes sooner; the stand-in tick never wakes the loop while blocks come."""
    world, source, reader, sent, first = _run(monkeypatch, rates_hz)
    end = world.t0 + RUN_S
    deadlines = [d for hz in rates_hz.values() for d in _deadlines(hz, first, end)]
    due_reads = sorted({math.ceil((d - world.t0) / PERIOD_S - 1e-9) for d in deadlines})   # truth: the rates
    max_reads = math.ceil(process_source.HANDOVER_MAX_S / PERIOD_S - 1e-9)
    block_reads = [round((ts - world.t0) / PERIOD_S) for _, _, ts in source.blocks]
    for prev, got in zip(block_reads[2:], block_reads[3:]):     # after the start-up's first two
        next_due = min((r for r in due_reads if r > prev), default=math.inf)
        assert got == min(next_due, prev + max_reads), (prev, got, next_due)
    assert block_reads[-1] * PERIOD_S > RUN_S - 2 * process_source.HANDOVER_MAX_S
    assert reader.counters.wakes - len(source.blocks) <= 2      # the ticks before the first block only


def test_the_stand_in_tick_keeps_the_outputs_going_when_the_chip_stops(monkeypatch):
    world, source, reader, sent, first = _run(monkeypatch, AUTOPILOT_RATES_HZ, stop_reads_at=4.0)
    sys_times = [t for m, t, _ in sent if m == SYS]
    assert len(sys_times) == 10                           # 1 Hz over the 10 s, six of them without a sample
    assert max(b[0] for b in source.blocks) < world.t0 + 4.1
    vpe_after = [t for m, t, _ in sent if m == VPE and t > world.t0 + 4.1]
    assert len(vpe_after) >= 30 * 5                       # the schedule keeps its rate on the tick (200 Hz)
