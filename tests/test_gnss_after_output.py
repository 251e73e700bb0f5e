"""A GNSS receiver's fix waits behind the outputs due (#28's p99, docs/daemon.md "Session 42 (gnsslat)").

The loop's order of work: when the receiver's descriptor becomes readable, GnssTask unwatches it and asks the sample
reader to run its poll at the end of the reader's next wake (SampleReader.after_output), after the outputs of the
samples that wake took were sent. Checked by the order of the calls (a fake loop and a stepped clock for the task; the
reader on a real loop with a pipe as its source, ordering only, no figure of time), never by wall time."""

from __future__ import annotations

import asyncio
import os

from ahrsd.core.gnss import make_fix
from ahrsd.daemon.config import GnssConfig
from ahrsd.daemon.gnss_task import GnssTask
from ahrsd.drivers.gnss.backend import GnssBackend, GnssHealth, GnssLinkState

from support.fake_aided import GateCounters, WithoutLeverArmCheck
from test_reader_wakes import _drive, _hand_over_and_wait, _rig


class FdBackend(GnssBackend):
    """A receiver with a descriptor (a pipe's read end, as a serial port's): `read()` gives the fixes queued."""

    description = "a receiver on a descriptor"

    def __init__(self):
        self.fd, self._w = os.pipe()
        self.queued: list = []
        self.reads = 0

    def fileno(self) -> int:
        return self.fd

    def read(self):
        self.reads += 1
        out, self.queued = self.queued, []
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


FIX = make_fix(10.0, 47.0, 8.0, 500.0, [3.0, -4.0, 0.0], h_acc_m=1.5, v_acc_m=2.5, s_acc_m_s=0.2, num_sats=9)


def _task(after_output):
    t = [10.0]
    backend, est, loop = FdBackend(), Recorder(), FakeLoop()
    task = GnssTask(backend, GnssConfig(), clock=lambda: t[0], estimator=Hook(est), statustext=lambda *a: None)
    task.open(loop, after_output=after_output)
    return task, backend, est, loop


def test_a_readable_receiver_is_read_after_the_outputs_not_at_once():
    deferred: list = []
    task, backend, est, loop = _task(deferred.append)
    try:
        backend.queued = [FIX]
        loop.readers[backend.fd]()                  # the descriptor became readable
        assert est.fixes == [] and backend.reads == 0    # nothing read in front of the outputs
        assert backend.fd not in loop.readers       # unwatched: a level-triggered descriptor would wake the loop again
        assert len(deferred) == 1
        deferred.pop()()                            # the reader's wake ends: its outputs were sent
        assert est.fixes == [FIX] and backend.reads == 1
        assert backend.fd in loop.readers           # watched again for the next fix
        backend.queued = [make_fix(10.2, 47.0, 8.0, 500.0, [3.0, -4.0, 0.0], h_acc_m=1.5, v_acc_m=2.5,
                                   s_acc_m_s=0.2, num_sats=9)]
        loop.readers[backend.fd]()
        loop.readers.get(backend.fd, lambda: None)()     # (unwatched: no second wake can ask again)
        assert len(deferred) == 1                   # one deferred poll however often it was readable
        deferred.pop()()
        assert [f.t_s for f in est.fixes] == [10.0, 10.2]
    finally:
        task.close()


def test_one_deferred_poll_while_the_tick_watches_the_descriptor_again():
    """The housekeeping tick polls meanwhile (a stalled reader) and re-watches the descriptor; a second readable
    wake before the deferred poll ran asks for no second one."""
    deferred: list = []
    task, backend, est, loop = _task(deferred.append)
    try:
        backend.queued = [FIX]
        loop.readers[backend.fd]()
        task.tick(10.1)                             # the tick reads the fix: a reader that does not wake loses none
        assert est.fixes == [FIX] and backend.fd in loop.readers
        loop.readers[backend.fd]()
        assert len(deferred) == 1
        deferred.pop()()
        assert est.fixes == [FIX]                   # the deferred poll found nothing more
    finally:
        task.close()


def test_without_a_reader_to_wait_for_a_readable_receiver_is_read_at_once():
    task, backend, est, loop = _task(None)
    try:
        backend.queued = [FIX]
        loop.readers[backend.fd]()
        assert est.fixes == [FIX] and backend.fd in loop.readers
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
