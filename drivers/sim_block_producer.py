"""The simulated chip's silicon in a process of its own: the simulation stream (truth trajectory, sensor
errors: `ahrsd.simulation.open_stream`) computed ahead in a child process, into shared memory.

The real ADIS16405 computes its samples in silicon, beside the reader, with no host CPU; the simulated one
computes them in Python and numpy, milliseconds per block of 256 samples. That work must not compete with the
reader in real time: in the reader's process it holds the reader's GIL at the moments it must read
(bench/reader_lateness.py), and a producer that computes a block only when the chip needs it makes every read
wait whenever the producer is short of CPU. So the producer runs ahead: it fills a ring of SLOTS blocks (about
10 s of samples at 819.2 SPS) in a shared memory file (memfd) and tells the chip through a pipe, one byte a
block, when a block is whole; the chip copies a block out when its clock reaches it and hands the slot back
with one byte on the producer's stdin. The chip's clock decides when a sample is readable (its data-ready time,
drivers.simulated): a sample is lost only when the reader comes late, as on the real chip, which has no FIFO.
The chip waits for the producer only at power-on (the chip's clock starts once the first block is ready) or
when the producer has fallen more than the whole ring behind — counted (`producer_waits`) and, where the reader
runs at real-time priority, prevented: the reader gives the producer its own priority (drivers.threaded_source),
so nothing the reader waits on runs below it.

Run as `python -m ahrsd.drivers.sim_block_producer SCENARIO RATE_HZ SEED ERRORS START_S BLOCK SLOTS FD`: FD is
the shared memory file (HEADER bytes, then SLOTS blocks of BLOCK rows of COLUMNS float64s); it writes one byte
on stdout per block made, reads one byte on stdin per slot handed back, and ends at the end of stdin or when
stdout is closed (the chip closed, or its process ended). A rate change (the chip's SMPL_PRD written) restarts
the stream in the same process (`ProducedStream.restart`: RESTART, then the new rate and start time as two
float64s on stdin; the producer empties its ring and answers RESTART on stdout before the new stream's blocks):
a new process would import the simulator again, about half a CPU-second, at every daemon start with a
configured rate. A subprocess rather than multiprocessing: the chip
may itself live in a daemonic reader process (drivers.process_source), which multiprocessing does not let have
children.
"""

from __future__ import annotations

import mmap
import os
import select
import struct
import subprocess
import sys
import time

import numpy as np

from ahrsd.drivers.sim_block_stream import ChipBlock

SLOTS = 32               # blocks computed ahead: 10 s of samples at 819.2 SPS
POWER_ON_TIMEOUT_S = 120.0   # the producer imports the simulator (numba kernels compile on a first run)
HEADER_BYTES = 64        # int64 at 0: which truth columns the stream has (bit 0 attitude, bit 1 gyro)
# (name, width) of a block row, in order; the truth columns are zero when the stream has none
COLUMNS = (("t_s", 1), ("gyro_rad_s", 3), ("accel_m_s2", 3), ("mag_ut", 3), ("temp_c", 1), ("truth_q_wxyz", 4),
           ("truth_gyro_rad_s", 3))
ROW = sum(w for _, w in COLUMNS)
_TRUTH_Q, _TRUTH_GYRO = 1, 2
BLOCK_DONE = b"\x01"     # stdout: a block is whole; stdin: a slot is handed back
RESTART = b"\x02"        # stdin: RESTART + _RESTART_ARGS (rate_hz, start_s); stdout: the old stream's blocks end here
_RESTART_ARGS = struct.Struct("<dd")


def _columns() -> dict[str, slice]:
    out, i = {}, 0
    for name, width in COLUMNS:
        out[name] = slice(i, i + width)
        i += width
    return out


_COL = _columns()


def _ring(buf, block: int, slots: int) -> np.ndarray:
    return np.ndarray((slots, block, ROW), dtype=np.float64, buffer=buf, offset=HEADER_BYTES)


class ProducedStream:
    """A simulation stream computed ahead in a child process (module doc): a drivers.sim_block_stream.BlockStream."""

    computed_elsewhere = True          # the chip's reads never compute: the blocks are made ahead
    waited_s = 0.0                     # how long the last next_block waited for the producer (ring empty)
    pid: int | None

    def __init__(self, scenario: str, rate_hz: float, seed: int, errors: str, start_s: float, block: int,
                 slots: int = SLOTS):
        self._block, self._slots = block, slots
        size = HEADER_BYTES + slots * block * ROW * 8
        fd = os.memfd_create("ahrsd-sim-chip-blocks")
        try:
            os.ftruncate(fd, size)
            self._mem = mmap.mmap(fd, size)
            self._proc = subprocess.Popen(
                [sys.executable, "-m", "ahrsd.drivers.sim_block_producer", scenario, repr(float(rate_hz)),
                 str(int(seed)), errors, repr(float(start_s)), str(block), str(slots), str(fd)],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, pass_fds=(fd,), close_fds=True, bufsize=0)
        finally:
            os.close(fd)
        self._ring = _ring(self._mem, block, slots)
        self._made = 0          # blocks the producer said are whole
        self._taken = 0         # blocks copied out (and their slots handed back)
        self.pid = self._proc.pid
        # power-on: the chip's clock starts once the first block is there (drivers.simulated)
        self._wait_for_blocks(POWER_ON_TIMEOUT_S)
        self._truth = int(np.frombuffer(self._mem, dtype=np.int64, count=1)[0])

    def _wait_for_blocks(self, timeout_s: float | None) -> None:
        out = self._proc.stdout.fileno()
        if timeout_s is not None and not select.select([out], [], [], timeout_s)[0]:
            self.close()
            raise RuntimeError(f"the simulated chip's block producer made no block in {timeout_s:g} s")
        got = os.read(out, 4 * self._slots)
        if not got:
            raise RuntimeError(f"the simulated chip's block producer ended (exit code {self._proc.poll()})")
        self._made += len(got)

    def restart(self, rate_hz: float, start_s: float) -> None:
        """The same scenario from `start_s` at `rate_hz` (the chip's rate changed), computed by the same process;
        returns once the new stream's first block is whole (the chip's new sample grid starts then)."""
        try:
            self._proc.stdin.write(RESTART + _RESTART_ARGS.pack(float(rate_hz), float(start_s)))
        except BrokenPipeError as exc:
            raise RuntimeError(f"the simulated chip's block producer ended (exit code {self._proc.poll()})") from exc
        out = self._proc.stdout.fileno()
        while True:       # the old stream's blocks announced before the producer read RESTART are not wanted
            if not select.select([out], [], [], POWER_ON_TIMEOUT_S)[0]:
                self.close()
                raise RuntimeError(f"the simulated chip's block producer did not restart in {POWER_ON_TIMEOUT_S:g} s")
            got = os.read(out, 4 * self._slots)
            if not got:
                raise RuntimeError(f"the simulated chip's block producer ended (exit code {self._proc.poll()})")
            at = got.find(RESTART)
            if at >= 0:
                self._made, self._taken = len(got) - at - 1, 0
                break
        if self._made == 0:
            self._wait_for_blocks(POWER_ON_TIMEOUT_S)
        self._truth = int(np.frombuffer(self._mem, dtype=np.int64, count=1)[0])

    def blocks_ahead(self) -> int:
        """Blocks made and not yet taken (non-blocking)."""
        while select.select([self._proc.stdout], [], [], 0)[0]:
            got = os.read(self._proc.stdout.fileno(), 4 * self._slots)
            if not got:
                break
            self._made += len(got)
        return self._made - self._taken

    def next_block(self, n: int) -> ChipBlock:
        if n != self._block:
            raise ValueError(f"the producer computes {self._block}-sample blocks, {n} were asked")
        self.waited_s = 0.0
        if self._made == self._taken:          # the producer is behind: the chip counts the wait
            t0 = time.monotonic()
            self._wait_for_blocks(None)
            self.waited_s = time.monotonic() - t0
        rows = self._ring[self._taken % self._slots]
        cols = {name: np.array(rows[:, s]) for name, s in _COL.items()}
        self._taken += 1
        try:
            self._proc.stdin.write(BLOCK_DONE)    # the slot is free again
        except BrokenPipeError as exc:
            raise RuntimeError(f"the simulated chip's block producer ended (exit code {self._proc.poll()})") from exc
        return ChipBlock(cols["t_s"][:, 0], cols["gyro_rad_s"], cols["accel_m_s2"], cols["mag_ut"],
                         cols["temp_c"][:, 0], cols["truth_q_wxyz"] if self._truth & _TRUTH_Q else None,
                         cols["truth_gyro_rad_s"] if self._truth & _TRUTH_GYRO else None)

    def close(self) -> None:
        for pipe in (self._proc.stdout, self._proc.stdin):    # either ends the producer
            try:
                pipe.close()
            except OSError:
                pass
        try:
            self._proc.wait(2.0)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait(1.0)
        self._ring = None
        try:
            self._mem.close()
        except BufferError:                    # a view still exported: the mapping goes with the last one
            pass


def main(argv: list[str]) -> int:
    import signal

    from ahrsd.simulation import open_stream

    signal.signal(signal.SIGINT, signal.SIG_IGN)          # its chip's owner ends it (Ctrl-C reaches the group)
    out = os.dup(1)
    os.dup2(2, 1)                                          # stray prints go to stderr, not into the pipe
    scenario, rate_hz, seed, errors, start_s, block, slots, fd = argv
    block, slots = int(block), int(slots)
    mem = mmap.mmap(int(fd), HEADER_BYTES + slots * block * ROW * 8)
    ring = _ring(mem, block, slots)
    def opened(rate_hz: str | float, start_s: str | float):
        return open_stream(scenario, rate_hz=float(rate_hz), seed=int(seed), errors=errors, start_s=float(start_s))

    stream = opened(rate_hz, start_s)
    inp = sys.stdin.buffer.raw
    made = freed = 0
    unread = b""            # what the chip sent and is not handled yet (a RESTART may arrive in pieces)
    while True:
        # the chip's messages: waited for while the ring is full, else taken as they come
        while made - freed >= slots or select.select([inp], [], [], 0)[0]:
            got = inp.read(4096)
            if not got:
                return 0
            unread += got
            while unread:
                if unread[:1] == BLOCK_DONE:
                    freed, unread = freed + 1, unread[1:]
                elif len(unread) > _RESTART_ARGS.size:
                    stream = opened(*_RESTART_ARGS.unpack_from(unread, 1))
                    unread = unread[1 + _RESTART_ARGS.size:]
                    made = freed = 0                       # the chip discards the old blocks
                    try:
                        os.write(out, RESTART)
                    except BrokenPipeError:                # the chip closed meanwhile
                        return 0
                else:
                    break                                  # the rest of a RESTART is still on its way
        blk = ChipBlock.of(stream.next_block(block))
        if len(blk.t_s) != block:
            raise ValueError(f"the stream made {len(blk.t_s)} samples, {block} were asked")
        rows = ring[made % slots]
        truth = 0
        values = blk.columns()
        for name, s in _COL.items():
            value = values[name]
            if value is None:
                rows[:, s] = 0.0
                continue
            rows[:, s] = np.asarray(value, dtype=np.float64).reshape(block, -1)
            truth |= {"truth_q_wxyz": _TRUTH_Q, "truth_gyro_rad_s": _TRUTH_GYRO}.get(name, 0)
        if made == 0:
            np.frombuffer(mem, dtype=np.int64, count=1)[0] = truth
        made += 1
        try:
            os.write(out, BLOCK_DONE)                      # after the rows: the pipe orders the two
        except BrokenPipeError:                            # the chip closed, or its process ended
            return 0
        # a short sleep between blocks: at the reader's SCHED_FIFO priority, filling the ring in one go would
        # run without blocking for longer than a unit's LimitRTTIME= allows (RLIMIT_RTTIME, systemd/ahrsd.service)
        time.sleep(0.0001)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
