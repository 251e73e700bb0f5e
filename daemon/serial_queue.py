"""A non-blocking, bounded, priority-admitting output queue for a serial MAVLink link.

pymavlink writes to a serial port with pyserial's blocking `write`: a port that cannot keep up (a baud rate too
low for the configured outputs, a stalled USB adapter, a pseudo-terminal nobody reads) would stall the whole
event loop — the sensor reader included. This queue takes pymavlink's place as the writer (`mav.file`): the
port's descriptor is made non-blocking, bytes go out with `os.write` as far as the line takes them and the
rest is written when the descriptor is writable again (`loop.add_writer`), so a frame is never cut and
nothing ever blocks.

Admission: the bytes waiting (in this queue and, on a real UART, in the kernel's output buffer, TIOCOUTQ) are
bounded to `capacity_bytes` (`queue_s` of line time, QUEUE_SECONDS by default). A message of priority p is admitted only while the
fill stays under ADMIT_FRACTION[p] of that bound, so as the line falls behind, the highest priority numbers
(diagnostics: IMU data, ATTITUDE) are refused first and priority 0 (VISION_POSITION_ESTIMATE, HEARTBEAT)
last. Refusals are counted per priority.
"""

from __future__ import annotations

import array
import fcntl
import logging
import os
import termios

log = logging.getLogger(__name__)

QUEUE_SECONDS = 0.1          # at most this much line time waits: the heading's latency stays bounded
MIN_QUEUE_BYTES = 512        # room for a few of the largest frames on a slow line
ADMIT_FRACTION = (1.0, 0.75, 0.5, 0.25)   # by priority 0, 1, 2, 3+


def admit_fraction(priority: int) -> float:
    return ADMIT_FRACTION[min(max(priority, 0), len(ADMIT_FRACTION) - 1)]


def kernel_output_queue_bytes(fd: int) -> int:
    """Bytes in the tty's kernel output buffer (0 where the driver does not report it, e.g. a pty)."""
    buf = array.array("i", [0])
    try:
        fcntl.ioctl(fd, termios.TIOCOUTQ, buf, True)
    except OSError:
        return 0
    return buf[0]


class SerialOutQueue:
    """`write(buf)` for pymavlink (`conn.mav.file = queue`); set `priority` before each message."""

    def __init__(self, fd: int, line_bytes_per_s: float, loop, counters, *, queue_s: float = QUEUE_SECONDS):
        self.fd = fd
        self.loop = loop
        self.counters = counters            # mavlink_io.LinkCounters: tx_dropped, tx_dropped_by_priority
        self.capacity_bytes = max(MIN_QUEUE_BYTES, int(line_bytes_per_s * queue_s))
        self.priority = 0
        self.accepted_last = True
        self._buf = bytearray()
        self._writer = False
        self.write_errors = 0
        os.set_blocking(fd, False)

    def waiting_bytes(self) -> int:
        return len(self._buf) + kernel_output_queue_bytes(self.fd)

    def admits(self, frame_sizes) -> bool:
        """Would frames of these sizes (bytes, at `priority`) all be admitted, written one after the other now? The
        port drains meanwhile, which only makes room, so a yes holds for writes that follow at once."""
        fill = self.waiting_bytes()
        limit = self.capacity_bytes * admit_fraction(self.priority)
        for size in frame_sizes:
            if fill > 0 and fill + size > limit:
                return False
            fill += size
        return True

    def refuse(self, frames: int = 1) -> None:
        """Count `frames` frames of `priority` as dropped."""
        self.accepted_last = False
        self.counters.tx_dropped += frames
        by_prio = self.counters.tx_dropped_by_priority
        by_prio[self.priority] = by_prio.get(self.priority, 0) + frames

    def write(self, data) -> int:
        if not self.admits((len(data),)):
            self.refuse()
            return 0
        self.accepted_last = True
        self._buf += data
        self._flush()
        return len(data)

    def _flush(self) -> None:
        while self._buf:
            try:
                n = os.write(self.fd, self._buf)
            except BlockingIOError:
                break
            except OSError as exc:      # device gone: the reader side notices and reconnects
                self.write_errors += 1
                if self.write_errors == 1:
                    log.warning("serial write failed: %s", exc)
                self._buf.clear()
                break
            if n <= 0:
                break
            del self._buf[:n]
        want_writer = bool(self._buf)
        if want_writer != self._writer:
            try:
                if want_writer:
                    self.loop.add_writer(self.fd, self._flush)
                else:
                    self.loop.remove_writer(self.fd)
                self._writer = want_writer
            except (OSError, ValueError):   # descriptor closed under us
                self._writer = False

    def close(self) -> None:
        if self._writer:
            try:
                self.loop.remove_writer(self.fd)
            except (OSError, ValueError):
                pass
            self._writer = False
        self._buf.clear()
