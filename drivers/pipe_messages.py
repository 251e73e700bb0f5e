"""The messages on the daemon's end of the reader process's pipe (drivers.process_source), read as they arrive:
everything the pipe holds in one `read()`, split at the length headers multiprocessing's `Connection.send_bytes`
writes (a 4-byte big-endian signed length, then the bytes; -1 and an 8-byte length for a message of 2 GiB or
more, which this pipe never carries).

Why: `Connection.poll(0)` and `recv_bytes` cost a poll, two reads (the header, then the bytes, through a BytesIO)
and a last poll that finds nothing, for every message, on the event loop, at every hand-over: one read a look is
what the descriptor's readiness asks for. The descriptor is made non-blocking, so a look that finds nothing (the
stand-in tick) does not wait; a message cut by a read waits in the buffer for its rest.
"""

from __future__ import annotations

import os
import struct
from collections import deque

_HEADER = struct.Struct("!i")
_LONG_HEADER = struct.Struct("!Q")


class PipeMessages:
    """The complete messages read from `fd` (a multiprocessing Connection's descriptor, set non-blocking here) and
    not yet taken: `next()` gives them in order, reading the descriptor once when none is left."""

    READ_BYTES = 1 << 16

    def __init__(self, fd: int):
        self._fd = fd
        os.set_blocking(fd, False)
        self._buf = b""                   # the bytes of a message not complete yet
        self._ready: deque[memoryview] = deque()

    def next(self, read: bool = True) -> memoryview | None:
        """The next complete message, or None when there is none. read: when none is buffered, read what the
        pipe holds first (once; a read that fills READ_BYTES is followed by another, the pipe may hold more).
        Raises EOFError when the other end closed, OSError when the read fails."""
        ready = self._ready
        if not ready and read:
            while self._read_once():
                pass
        return ready.popleft() if ready else None

    def _read_once(self) -> bool:
        """One read of the pipe, its complete messages queued; True when it filled READ_BYTES (read again)."""
        try:
            data = os.read(self._fd, self.READ_BYTES)
        except BlockingIOError:
            return False
        if not data:
            raise EOFError("the reader process closed its end of the pipe")
        full = len(data) == self.READ_BYTES
        if self._buf:
            data = self._buf + data
        view, pos, end = memoryview(data), 0, len(data)
        while end - pos >= 4:
            size, = _HEADER.unpack_from(data, pos)
            start = pos + 4
            if size == -1:
                if end - start < 8:
                    break
                size, = _LONG_HEADER.unpack_from(data, start)
                start += 8
            if end - start < size:
                break
            self._ready.append(view[start:start + size])
            pos = start + size
        self._buf = data[pos:] if pos < end else b""
        return full

    def drain(self) -> list[memoryview]:
        """The complete messages buffered, taken; the descriptor made blocking again (the Connection reads on)."""
        out = list(self._ready)
        self._ready.clear()
        os.set_blocking(self._fd, True)
        return out

    @property
    def partial(self) -> bytes:
        """The start of a message read but not complete (the Connection must not read on after it)."""
        return self._buf
