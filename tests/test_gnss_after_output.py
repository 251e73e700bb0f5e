"""A GNSS receiver's fix waits behind the outputs due (#28's p99, docs/daemon.md "Session 42 (gnsslat)").

The loop's order of work: when the receiver's descriptor becomes readable, GnssTask reads it at once (each fix stamped
at its arrival, as before) and asks the sample reader to deliver the fixes at the end of the reader's next wake
(SampleReader.after_output), after the outputs of the samples that wake took were sent. Checked by the order of the calls (a fake loop and a stepped clock for the task; the
reader on a real loop with a pipe as its source, ordering only, no figure of time), never by wall time."""

from __future__ import annotations

import dataclasses
import os

from ahrsd.core.gnss import make_fix
from ahrsd.daemon.config import GnssConfig
from ahrsd.daemon.gnss_task import GnssTask
from ahrsd.drivers.gnss.backend import GnssBackend, GnssHealth, GnssLinkState

from support.fake_aided import GateCounters, WithoutLeverArmCheck
from support.pipe_reader import _drive, _hand_over_and_wait, _rig


class FdBackend(GnssBackend):
    """A receiver with a descriptor (a pipe's read end, as a serial port's): `read()` gives the fixes queued, each
    stamped at the clock's time of the read (a serial fix's arrival stamp)."""

    description = "a receiver on a descriptor"

    def __init__(self, clock):
        self.fd, self._w = os.pipe()
        self.clock = clock
        self.queued: list = []
        self.reads = 0

    def fileno(self) -> int:
        return self.fd

    def read(self):
        self.reads += 1
        out, self.queued = [dataclasses.replace(f, t_s=self.clock()) for f in self.queued], []
        return out

    def health(self) -> GnssHealth:
        return GnssHealth(GnssLinkState.OK)

    def stats(self) -> dict[str, dict]:
        return {"fd": {"reads": self.reads}}

    def close(self) -> None:
        os.close(self.fd)
        os.close(self._w)


class FakeLoop:
    """The two calls GnssTask makes of the event loop: the watched descriptors and their callbacks."""

    def __init__(self):
        self.readers: dict[int, object] = {}

    def add_reader(self, fd, callback) -> None:
        self.readers[fd] = callback

    def remove_reader(self, fd) -> None:
        del self.readers[fd]


class Recorder(WithoutLeverArmCheck):
    name = "recorder"

    def __init__(self):
        self.fixes: list = []
        self.gnss_counters = GateCounters()

    def update_gnss(self, fix) -> int:
        self.fixes.append(fix)
        return 0


class Hook:
    def __init__(self, estimator):
        self.estimator, self.last_estimate = estimator, None


FIX = make_fix(0.0, 47.0, 8.0, 500.0, [3.0, -4.0, 0.0], h_acc_m=1.5, v_acc_m=2.5, s_acc_m_s=0.2, num_sats=9)


class Clock:
    t = 10.0

    def __call__(self) -> float:
        return self.t


def _task(after_output):
    clock = Clock()
    backend, est, loop = FdBackend(clock), Recorder(), FakeLoop()
    task = GnssTask(backend, GnssConfig(), clock=clock, estimator=Hook(est), statustext=lambda *a: None)
    task.open(loop, after_output=after_output)
    return task, backend, est, loop, clock


def test_a_readable_receiver_is_read_at_once_and_its_fixes_delivered_after_the_outputs():
    deferred: list = []
    task, backend, est, loop, clock = _task(deferred.append)
    try:
        backend.queued = [FIX]
        loop.readers[backend.fd]()                  # the descriptor became readable at 10.0 s
        assert backend.reads == 1 and est.fixes == []    # read (stamped) now, nothing delivered in front of the outputs
        assert backend.fd in loop.readers and len(deferred) == 1
        clock.t = 10.2
        backend.queued = [FIX]
        loop.readers[backend.fd]()                  # the next fix before the reader's wake ended
        assert backend.reads == 2 and len(deferred) == 1     # one deferred delivery for both
        clock.t = 10.25
        deferred.pop()()                            # the reader's wake ends: its outputs were sent
        assert [f.t_s for f in est.fixes] == [10.0, 10.2]    # each with the stamp of its own read, in order
    finally:
        task.close()


def test_the_tick_delivers_the_fixes_waiting_first():
    """The housekeeping tick polls meanwhile (a stalled reader): the fixes read before go first, then the new ones."""
    deferred: list = []
    task, backend, est, loop, clock = _task(deferred.append)
    try:
        backend.queued = [FIX]
        loop.readers[backend.fd]()
        clock.t = 10.1
        backend.queued = [FIX]
        task.tick(10.1)
        assert [f.t_s for f in est.fixes] == [10.0, 10.1]
        deferred.pop()()
        assert len(est.fixes) == 2                  # the deferred delivery found nothing more
    finally:
        task.close()


def test_without_a_reader_to_wait_for_a_readable_receiver_is_delivered_at_once():
    task, backend, est, loop, clock = _task(None)
    try:
        backend.queued = [FIX]
        loop.readers[backend.fd]()
        assert [f.t_s for f in est.fixes] == [10.0] and backend.fd in loop.readers
    finally:
        task.close()


def test_the_reader_runs_work_after_output_once_after_the_next_wake_s_outputs():
    source, reader, seen, published = _rig(poll_hz=1.0)    # the tick 1 s: the next wake is the block's
    order: list = []
    reader.listeners.add(lambda s, e: order.append(("sample", s.counter)))
    reader.outputs.publish = lambda now: order.append("publish")

    async def body():
        await _hand_over_and_wait(source, seen, 2)          # the reader runs; its first wakes done
        order.clear()
        reader.after_output(lambda: order.append("fix"))
        await _hand_over_and_wait(source, seen, 3)
        await _hand_over_and_wait(source, seen, 1)

    _drive(reader, source, body)
    assert order == [("sample", 2), ("sample", 3), ("sample", 4), "publish", "fix", ("sample", 5), "publish"]


def test_work_after_output_that_raises_leaves_the_reader_running():
    source, reader, seen, _ = _rig(poll_hz=1.0)

    def broken():
        raise RuntimeError("a faulty part")

    async def body():
        await _hand_over_and_wait(source, seen, 1)
        reader.after_output(broken)
        await _hand_over_and_wait(source, seen, 1)
        await _hand_over_and_wait(source, seen, 1)

    _drive(reader, source, body)
    assert seen == [0, 1, 2]                        # the blocks after it were taken: the reader went on


def test_while_the_reader_does_not_run_work_after_output_runs_at_once():
    """No wake will come (the reader not started, or stopped): a fix must not wait for one."""
    source, reader, _, _ = _rig(poll_hz=1.0)
    ran: list = []
    try:
        reader.after_output(lambda: ran.append("fix"))
        assert ran == ["fix"]
    finally:
        source.close()


def test_the_daemon_defers_a_receiver_s_fixes_to_its_reader(tmp_path):
    from service_rig import gcs_socket, start_service, stop_service
    from ahrsd.drivers.gnss.simulated import SimulatedGnssReceiver

    gcs = gcs_socket()
    with SimulatedGnssReceiver(protocol="ubx") as rx:
        service, loop = start_service(gcs, tmp_path / "state",
                                      gnss=GnssConfig(source="serial", device=rx.device, latency_s=0.1))
        try:
            assert service.gnss._after_output == service.reader.after_output
        finally:
            stop_service(service, loop)
            gcs.close()
