"""The simulated chip's silicon in a process of its own: the simulation stream (truth trajectory, sensor
errors: `ahrsd.simulation.open_stream`) computed in a child process, blocks handed back through a pipe.

The real ADIS16405 computes its samples in silicon, beside the reader; the simulated one computes them in
Python and numpy, milliseconds per block of 256 samples. In the reader's process that work holds the reader's
GIL at the moments it must read (bench/reader_lateness.py measures it: a reader with the producer beside it is
late by up to 17 sample periods, without it by under 4), and the simulated chip then loses samples the real one
would not. `ProducedStream` has the stream's `next_block(n)` interface; it keeps AHEAD blocks requested, so a
block is ready (only unpickled in the reader's process) when the chip needs it.

Run as `python -m ahrsd.drivers.sim_block_producer SCENARIO RATE_HZ SEED ERRORS START_S`: reads 4-byte block
sizes on stdin, writes pickled blocks on stdout, ends at the end of stdin (the chip closed, or its process
ended). A subprocess rather than multiprocessing: the chip may itself live in a daemonic reader process
(drivers.process_source), which multiprocessing does not let have children.
"""

from __future__ import annotations

import fcntl
import os
import pickle
import struct
import subprocess
import sys
from dataclasses import dataclass

import numpy as np

F_SETPIPE_SZ = 1031      # fcntl.F_SETPIPE_SZ (Linux)
AHEAD = 8                # blocks computed ahead: 2.5 s of samples at 819.2 SPS (a producer short of CPU)
PIPE_BYTES = 1 << 19     # F_SETPIPE_SZ of the blocks' pipe: AHEAD blocks fit whole, read without waiting
_SIZE = struct.Struct("<I")


@dataclass
class ChipBlock:
    """What the simulated chip takes from a stream block (drivers.simulated._refill)."""

    t_s: np.ndarray
    gyro_rad_s: np.ndarray
    accel_m_s2: np.ndarray
    mag_ut: np.ndarray
    temp_c: np.ndarray
    truth_q_wxyz: np.ndarray | None
    truth_gyro_rad_s: np.ndarray | None

    @classmethod
    def of(cls, blk) -> "ChipBlock":
        return cls(blk.t_s, blk.gyro_rad_s, blk.accel_m_s2, blk.mag_ut, blk.temp_c,
                   getattr(blk, "truth_q_wxyz", None), getattr(blk, "truth_gyro_rad_s", None))


class ProducedStream:
    """A simulation stream computed in a child process (module doc)."""

    computed_elsewhere = True          # the chip asks for blocks as it needs them: they are computed ahead

    def __init__(self, scenario: str, rate_hz: float, seed: int, errors: str, start_s: float, block: int):
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "ahrsd.drivers.sim_block_producer", scenario, repr(float(rate_hz)), str(int(seed)),
             errors, repr(float(start_s))], stdin=subprocess.PIPE, stdout=subprocess.PIPE, close_fds=True)
        try:        # a block bigger than the pipe would be read while the producer still writes it: waiting
            fcntl.fcntl(self._proc.stdout.fileno(), F_SETPIPE_SZ, PIPE_BYTES)
        except OSError:
            pass
        self._block = block
        for _ in range(AHEAD):
            self._request(block)

    def _request(self, n: int) -> None:
        self._proc.stdin.write(_SIZE.pack(n))
        self._proc.stdin.flush()

    def next_block(self, n: int):
        try:
            blk = pickle.load(self._proc.stdout)
        except EOFError as exc:
            raise RuntimeError(f"the simulated chip's block producer ended (exit code {self._proc.poll()})") from exc
        if len(blk.t_s) != n:
            raise ValueError(f"the producer computes {len(blk.t_s)}-sample blocks, {n} were asked")
        self._request(n)
        return blk

    def close(self) -> None:
        try:
            self._proc.stdin.close()
        except OSError:
            pass
        try:
            self._proc.wait(2.0)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait(1.0)
        self._proc.stdout.close()


def main(argv: list[str]) -> int:
    import signal

    from ahrsd.drivers.sim_block_producer import ChipBlock as Block     # not __main__'s: the chip unpickles it
    from ahrsd.simulation import open_stream

    signal.signal(signal.SIGINT, signal.SIG_IGN)          # its chip's owner ends it (Ctrl-C reaches the group)
    out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)                                          # stray prints go to stderr, not into the pipe
    scenario, rate_hz, seed, errors, start_s = argv
    stream = open_stream(scenario, rate_hz=float(rate_hz), seed=int(seed), errors=errors, start_s=float(start_s))
    inp = sys.stdin.buffer
    while True:
        head = inp.read(_SIZE.size)
        if len(head) < _SIZE.size:
            return 0
        try:
            blk = Block.of(stream.next_block(_SIZE.unpack(head)[0]))
            out.write(pickle.dumps(blk, protocol=pickle.HIGHEST_PROTOCOL))      # one write: whole in the pipe
            out.flush()
        except BrokenPipeError:                            # the chip's process ended without closing
            return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
