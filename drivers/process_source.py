"""The chip read in a child process (`[sensor] reader = "process"`, the default for the real and the simulated
chip): its own interpreter, hence its own GIL.

A reader thread in the daemon's process (drivers.threaded_source) waits for the GIL whenever another thread of
the daemon holds it, and under CPU contention the holder can be descheduled for milliseconds while the
real-time reader waits: priority inversion through the GIL. `bench/reader_gil.py` measures it (docs/drivers.md).
Here the same per-sample source and reader thread run in a child process started with "spawn" (a clean
interpreter: no event loop, threads or locks inherited); the child hands samples over through a pipe in blocks
(packed records), with the source's counters every 0.25 s and its errors as they happen. A samples message is
its packed records behind one tag byte, sent and received as bytes (`send_samples`, `receive`): the other
messages are pickled as multiprocessing does, and a pickle's first byte (0x80) is never the tag. The child starts
reading at the daemon's first `poll()` (start-up time is not counted as loss) and ends with the pipe.
"""

from __future__ import annotations

import functools
import gc
import logging
import math
import os
import select
import struct
import time
from multiprocessing.reduction import ForkingPickler
from types import SimpleNamespace
from typing import Callable

import numpy as np

from ahrsd.core.sample import ImuSample
from ahrsd.core.sample_block import SampleBlock
from ahrsd.drivers import errors as driver_errors
from ahrsd.drivers.handover_plan import HANDOVER_MAX_S, HandoverPlan
from ahrsd.drivers.pipe_messages import PipeMessages
from ahrsd.drivers.sample_record import SampleRecord
from ahrsd.drivers.source_interface import LiveSource
from ahrsd.drivers.source_settings import SensorSettings

log = logging.getLogger(__name__)

# When the child hands a block over (the daemon takes it as it arrives, SampleReader `ready_fd`, so each hand-over
# is a wake of the daemon's event loop, whose cost is mostly per wake: docs/daemon.md "Performance"): as
# drivers.handover_plan says (the daemon's next output deadline, told through `ProcessSource.hand_over_by`, and at
# the latest HANDOVER_MAX_S after the last hand-over, short of CHUNK_SAMPLES periods at the chip's fastest rate, so
# one message carries a block), and every HANDOVER_S while a backlog drains (a stalled daemon: one chunk a tick).
HANDOVER_S = 0.005
COUNTERS_EVERY_S = 0.25
START_TIMEOUT_S = 120.0       # the child imports the drivers (and, simulated, the simulator) and starts the chip
_RECORD = np.dtype([("t_s", "<f8"), ("gyro", "<f8", 3), ("accel", "<f8", 3), ("mag", "<f8", 3), ("temp_c", "<f8"),
                    ("supply_v", "<f8"), ("flags", "<i8"), ("diag", "<i8"), ("counter", "<i8")])
_WRITABLE = select.POLLOUT | select.POLLERR


_PACK_RECORD = struct.Struct("<12d3q").pack    # one _RECORD (packed, little-endian) from its 15 numbers
assert struct.calcsize("<12d3q") == _RECORD.itemsize


def pack(samples: list[ImuSample | SampleRecord]) -> bytes:
    """Samples as _RECORD bytes (struct: a numpy record assignment per sample costs several times more); a
    SampleRecord (the chip driver's, in this process) is those numbers already."""
    p = _PACK_RECORD
    return b"".join([p(*s) if type(s) is SampleRecord else
                     p(s.t_s, *s.gyro_rad_s.tolist(), *s.accel_m_s2.tolist(), *s.mag_ut.tolist(), s.temp_c,
                       s.supply_v, int(s.flags), s.diag_stat, s.counter) for s in samples])


_SAMPLES_TAG = b"S"           # the first byte of a samples message (a pickle's is 0x80: protocol 2 and later)
_SAMPLES_TAG_BYTE = _SAMPLES_TAG[0]


def send_samples(conn, samples: list[ImuSample | SampleRecord]) -> None:
    """One samples message: the tag and the packed records, as bytes (pickling them would build a pickler, and
    copy its dispatch table, for every message: multiprocessing's `send`)."""
    conn.send_bytes(_SAMPLES_TAG + pack(samples))


def receive(conn) -> tuple:
    """The next message from the other end: ("samples", the packed records) for a samples message, else the
    unpickled message (a tuple, or the daemon's "go" / "stop")."""
    return parse_message(conn.recv_bytes())


def parse_message(data: bytes | memoryview) -> tuple:
    """A message's bytes as `receive` gives it."""
    if data[0] == _SAMPLES_TAG_BYTE:
        return "samples", memoryview(data)[1:]
    return ForkingPickler.loads(data)


def unpack_block(data: bytes) -> SampleBlock:
    """The samples of one or more packed blocks (`pack`), concatenated, as columns: no ImuSample is built until
    one is asked for (the daemon calibrates the block's arrays at once: daemon.pipeline)."""
    rec = np.frombuffer(data, dtype=_RECORD)
    # column by column (a field access per record and row costs more than the estimator's step); gyro, accel
    # and mag lie side by side in a record: one (n, 9) copy
    floats = rec.view("<f8").reshape(len(rec), _RECORD.itemsize // 8)
    return SampleBlock(rec["t_s"].tolist(), floats[:, 1:10].copy(), rec["temp_c"].tolist(), rec["supply_v"].tolist(),
                       rec["flags"].tolist(), rec["diag"].tolist(), rec["counter"].tolist())


def unpack(data: bytes) -> list[ImuSample]:
    """The samples of one or more packed blocks (`pack`), concatenated."""
    return list(unpack_block(data))


def _chip_truth(src) -> dict | None:
    chip = src.chip
    if chip is None:
        return None
    return {"stats": dict(chip.stats), "sample_index": chip.sample_index, "injected": dict(chip.faults.injected),
            "t_origin": chip._t_origin}


def _child(sensor_cfg: SensorSettings, faults, conn, handover_at=None) -> None:
    import signal

    from ahrsd.drivers.source import open_source

    signal.signal(signal.SIGINT, signal.SIG_IGN)     # the daemon ends the reader (Ctrl-C reaches the group)
    try:
        # the chip's driver hands over records: this process only packs them (pack)
        src = open_source(sensor_cfg, faults=faults, samples_as_records=True)
    except Exception as exc:  # noqa: BLE001 - reported to the daemon, which says why it cannot start
        conn.send(("error", type(exc).__name__, str(exc)))
        return
    # the chip source's own description: its reader thread's ("read in a dedicated thread") is not the daemon's;
    # with reader "thread" open_source reads every chip (sim, spi, iio) through a ThreadedSource
    conn.send(("hello", src.inner.description, src.sample_rate_hz, _chip_truth(src)))
    # what start-up imported stays for good: out of the collector's sight, so that a full collection during
    # the reads (the reader thread pays for it, holding the GIL) does not walk every module's objects
    gc.collect()
    gc.freeze()
    gc.callbacks.append(_GC_PAUSES)
    try:
        if conn.recv() != "go":
            return
        # The hand-over runs in the reader thread, between reads: the main thread only waits for "stop",
        # blocked in recv() without the GIL. A second Python thread here would hold the reader's GIL at
        # times, and when the machine is short of CPU be descheduled while holding it (a priority inversion
        # that the reader's SCHED_FIFO cannot break: docs/drivers.md).
        # the shared double read in C (getattr): asked after every read
        wanted = None if handover_at is None else functools.partial(getattr, handover_at, "value")
        handover = _Handover(conn, src, wanted=wanted)
        src.after_read = handover.maybe_send
        src.log_realtime = False              # the child's log goes nowhere: the daemon logs what it is told
        src.start()
        while conn.recv() != "stop":
            pass
        src.close()                           # stop reading, then hand over the rest and the final counts
        try:
            tail = src.poll()
        except Exception:  # noqa: BLE001 - the sensor's failure, handed over already: at the stop only samples count
            tail = []
        rest = handover.pending + tail
        if rest:
            send_samples(conn, rest)
            handover.sent += len(rest)
        conn.send(("counters", handover.counters(), _chip_truth(src)))
    except (BrokenPipeError, EOFError, OSError):
        pass                                  # the daemon went away
    finally:
        src.close()


class _Handover:
    """From the reader thread, when the daemon's next output falls due (`wanted()`, CLOCK_MONOTONIC s) and at
    the latest HANDOVER_MAX_S after the last time (HANDOVER_S while a backlog drains): the samples read, the
    errors, and every COUNTERS_EVERY_S the source's counters, through the pipe to the daemon. A deadline is
    served once: the daemon tells the next one after it took the block. Never blocks the reader, and does a bounded amount of
    work a tick: a stalled daemon leaves the samples queued (what the reader took in `pending`, the rest in the
    reader's bounded buffer, drivers.threaded_source, which counts what it must drop), and once the daemon reads
    again they go one message a tick, in order.

    Why a send cannot block: the pipe is a Unix stream socket, which select() calls writable only while at most
    a quarter of its send buffer is in use (Linux unix_writable), and no message is larger than another eighth
    of it (`chunk_samples`), so a send made when select() says writable always fits.

    Why 32 samples a message: packing costs time per sample (several times more on a Raspberry Pi) and the tick
    runs between two reads, so after a stalled daemon a message of a few hundred samples holds the reader for
    most of a sample period (docs/drivers.md, the hand-over; bench/reader_floor.py: `hand-over tick`). 32 a tick
    drains 16 000 samples a second, twenty times the chip's rate: 10 s of backlog in half a second."""

    CHUNK_SAMPLES = 32

    def __init__(self, conn, src, room: Callable[[], bool] | None = None, wanted: Callable[[], float] | None = None):
        """room(): whether a message may be sent now without blocking (default: select() calls the pipe
        writable, as the class doc says). wanted(): the daemon's next output deadline (default: none, every
        HANDOVER_MAX_S only)."""
        self.conn, self.src = conn, src
        self.next_counters = 0.0
        self._wanted = wanted or (lambda: math.inf)
        self.plan = HandoverPlan(HANDOVER_MAX_S)      # when the next hand-over is (drivers.handover_plan)
        self.last_error, self.error_sent_at = None, -1.0
        self.pending: list[ImuSample] = []
        self.sent = 0                 # samples sent to the daemon: all the reader handed over, at the end
        self.chunk_samples = self.CHUNK_SAMPLES
        poller = select.poll()
        poller.register(conn.fileno(), select.POLLOUT)
        self._poll_out = poller.poll
        self._room = room or self._pipe_writable
        try:
            import socket

            with socket.socket(fileno=os.dup(conn.fileno())) as sock:
                sndbuf = sock.getsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF)
            self.chunk_samples = max(1, min(self.CHUNK_SAMPLES, sndbuf // 8 // _RECORD.itemsize - 1))
        except (OSError, AttributeError, ValueError):
            pass

    def _pipe_writable(self) -> bool:
        # what select() calls writable (POLLOUT or an error), from a poll object made once
        return any(events & _WRITABLE for _fd, events in self._poll_out(0))

    realtime_sent = False

    work_us_max = 0

    def maybe_send(self) -> None:
        now = time.monotonic()
        plan = self.plan
        plan.due_s = self._wanted()
        if now < plan.next_read_s():
            return
        plan.read_at(now)                 # a hand-over for HANDOVER_MAX_S before it leaves the deadline to come
        self._send(now)
        if self.pending:
            plan.latest_s = now + HANDOVER_S
        work_us = (time.monotonic() - now) * 1e6
        if work_us > self.work_us_max:
            self.work_us_max = int(work_us)

    def _send(self, now: float) -> None:
        conn, src = self.conn, self.src
        if not self.realtime_sent and src.realtime_refused is not None and self._room():
            self.realtime_sent = True
            conn.send(("realtime", src.realtime_refused))
        if not self.pending:
            try:
                self.pending = src.poll()
            except Exception as exc:  # noqa: BLE001 - the daemon counts and reports it (10 a second at most)
                error = (type(exc).__name__, str(exc))
                if (error != self.last_error or now - self.error_sent_at >= 0.1) and self._room():
                    conn.send(("error", *error))
                    self.last_error, self.error_sent_at = error, now
        if self.pending and self._room():       # one message a tick: a backlog costs the reader no read
            chunk, self.pending = self.pending[:self.chunk_samples], self.pending[self.chunk_samples:]
            send_samples(conn, chunk)
            self.sent += len(chunk)
        if now >= self.next_counters and self._room():
            self.next_counters = now + COUNTERS_EVERY_S
            conn.send(("counters", self.counters(), _chip_truth(src)))

    def counters(self) -> dict:
        return {**self.src.counters(), "handover_sent": self.sent, "handover_work_us_max": self.work_us_max,
                **_GC_PAUSES.counters()}


class _GcPauses:
    """The garbage collector's pauses in the reader process (each runs in the thread that allocates: the
    reader): how many, and the longest."""

    def __init__(self):
        self.count, self.max_us, self._t0 = 0, 0, 0.0

    def __call__(self, phase: str, info: dict) -> None:
        if phase == "start":
            self._t0 = time.perf_counter()
        else:
            self.count += 1
            self.max_us = max(self.max_us, int((time.perf_counter() - self._t0) * 1e6))

    def counters(self) -> dict:
        return {"reader_gc_collections": self.count, "reader_gc_pause_max_us": self.max_us}


_GC_PAUSES = _GcPauses()


class _ChipView:
    """What the daemon asks of a simulated chip (run_stats, the simulated GNSS receiver's clock), from the
    child's latest report."""

    def __init__(self, truth: dict):
        self.update(truth)
        self._t_origin = truth["t_origin"]

    def update(self, truth: dict) -> None:
        self.stats, self.sample_index = truth["stats"], truth["sample_index"]
        self.faults = SimpleNamespace(injected=truth["injected"])

    def now(self) -> float:
        return time.monotonic() - self._t_origin       # the simulated chip runs on CLOCK_MONOTONIC

    def helper_pids(self) -> list[int]:
        return []          # the chip's block producer is the reader process's child, given its priority there


class ProcessSource(LiveSource):
    """The configured chip source (sim or spi), read by drivers.threaded_source in a child process."""

    description: str
    sample_rate_hz: float
    per_sample = False
    monotonic_offset_s = 0.0

    def __init__(self, sensor_cfg: SensorSettings, faults=None):
        import multiprocessing

        ctx = multiprocessing.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self._messages: PipeMessages | None = None      # the raw reader, once the child said hello
        # the daemon's next output deadline, read by the child's reader thread between reads (one double in shared
        # memory: no message, no syscall, no lock: a torn read is impossible for an aligned double on the
        # platforms ahrsd runs on, and a stale one only moves a hand-over to the next read or HANDOVER_MAX_S)
        self._handover_at = ctx.RawValue("d", math.inf)
        # a plain SensorSettings with reader "thread": the child reads the chip itself, in a thread
        self._proc = ctx.Process(target=_child, args=(sensor_cfg.read_in_thread(), faults, child, self._handover_at),
                                 name="ahrsd-sensor-reader", daemon=True)
        self._proc.start()
        child.close()
        self._counters: dict = {}
        self.chip = None
        self._started = False
        if not self._conn.poll(START_TIMEOUT_S):
            self.close()
            raise driver_errors.BusError("the sensor reader process did not start")
        msg = self._conn.recv()
        if msg[0] == "error":
            self.close()
            raise _error(msg[1], msg[2])
        _, self.description, self.sample_rate_hz, truth = msg
        self.description += ", read in a reader process"
        if truth is not None:
            self.chip = _ChipView(truth)
        self.stats = {"blocks": 0, "samples": 0}
        self._last_polled: int | None = None
        # from here on the messages are read raw, one read a look (drivers.pipe_messages)
        self._messages = PipeMessages(self._conn.fileno())
        self.ready_fd = self._conn.fileno()       # readable when the child sent something: poll() then

    # the longest the child goes without handing over while the daemon takes its blocks (the reader's stand-in
    # tick waits that much longer: daemon.sample_reader)
    handover_max_s = HANDOVER_MAX_S

    def hand_over_by(self, t: float) -> None:
        """The daemon's next output deadline (CLOCK_MONOTONIC s; inf: none): the child hands its block over at its
        first read from then on."""
        self._handover_at.value = t

    def poll(self) -> list[ImuSample] | SampleBlock:
        """Every sample block the child sent since the last call, unpacked in one go into one SampleBlock (the
        child sends a block when an output falls due, `hand_over_by`, or after HANDOVER_MAX_S; the daemon polls
        when one arrives, `ready_fd`, or on its tick)."""
        conn = self._conn
        if not self._started:
            self._started = True
            conn.send("go")
        blocks: list[memoryview] = []
        error = None
        # one read of what the pipe holds (drivers.pipe_messages), then the messages it completed; a message that
        # arrives meanwhile makes the descriptor readable again (the next look). A closed pipe raises EOFError.
        messages = self._messages
        try:
            data = messages.next()
            while data is not None:
                msg = parse_message(data)
                kind = msg[0]
                if kind == "samples":
                    blocks.append(msg[1])
                elif kind == "counters":
                    self._counters = msg[1]
                    if msg[2] is not None and self.chip is not None:
                        self.chip.update(msg[2])
                elif kind == "error":
                    error = _error(msg[1], msg[2])
                    if blocks:
                        break
                elif kind == "realtime":
                    from ahrsd.drivers.threaded_source import log_realtime_priority

                    log_realtime_priority("sensor reader process", msg[1])
                data = messages.next(read=False)
        except (EOFError, OSError) as exc:
            raise driver_errors.BusError(f"the sensor reader process ended ({exc})") from exc
        out = unpack_block(b"".join(blocks)) if blocks else []
        self.stats["blocks"] += len(blocks)
        self.stats["samples"] += len(out)
        if not out and error is not None:
            raise error
        if out:
            self._last_polled = out.counter[-1]
        return out

    def counters(self) -> dict:
        c = dict(self._counters)
        c.update({f"process_{k}": v for k, v in self.stats.items()})
        return c

    def close(self) -> None:
        """Stop the child; the samples it had read but not handed over are kept in `undelivered` (with the
        final counters, they account for every index the child saw)."""
        self.undelivered: list[ImuSample] = []
        try:
            self._conn.send("stop" if self._started else "go")
            if not self._started:
                self._conn.send("stop")
            end = time.monotonic() + 3.0
            # the raw reader, whose buffer may hold messages already (made here when the start failed before it)
            messages = self._messages or PipeMessages(self._conn.fileno())
            while True:
                data = messages.next()
                if data is None:
                    left_s = end - time.monotonic()
                    if left_s <= 0 or not self._conn.poll(left_s):
                        break
                    continue
                msg = parse_message(data)
                if msg[0] == "samples":
                    self.undelivered += unpack(msg[1])
                elif msg[0] == "counters":
                    self._counters = msg[1]
                    if msg[2] is not None and self.chip is not None:
                        self.chip.update(msg[2])
        except (OSError, ValueError, EOFError):
            pass
        self.stats["undelivered"] = len(self.undelivered)
        if self.undelivered:
            # indices the child read (or lost) after the last sample the daemon took: the chip's truth has them
            last = self._last_polled if self._last_polled is not None else self.undelivered[0].counter - 1
            self._counters["reader_undelivered_at_close"] = self.undelivered[-1].counter - last
        self._proc.join(3.0)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join(1.0)
        self._conn.close()


def _error(name: str, message: str) -> Exception:
    cls = getattr(driver_errors, name, None)
    if not (isinstance(cls, type) and issubclass(cls, driver_errors.DriverError)):
        cls = driver_errors.BusError          # SensorUnavailable, OSError, ...: the bus is not usable now
    try:
        return cls(message)
    except TypeError:                         # SelfTestFailed, ProductIdMismatch take their fields
        return driver_errors.DriverError(message)
