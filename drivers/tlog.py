"""The MAVLink traffic log: every frame in and out, as a `.tlog` (the format of pymavlink's `mavlogfile` and
MAVProxy: per frame, the receive/send time as an 8-byte big-endian count of µs since the Unix epoch, then the
raw MAVLink frame). `mavlogdump.py`, MAVExplorer and `mavutil.mavlink_connection("x.tlog")` read it.

    tlog = TlogLog("/var/lib/ahrsd/logs")
    tlog.put(frame_bytes)                 # stamped now (wall clock); or tlog.put((unix_s, frame_bytes))
    tlog.close()

Rotation, the total cap, the bounded queue and the stop-on-full-disk behaviour are drivers/rotating_log.py's.
A file cut by a crash reads up to its last complete frame (the readers skip a torn tail).
"""

from __future__ import annotations

import struct
from pathlib import Path

from .rotating_log import RotatingLog

TLOG_PREFIX = "mavlink"
TLOG_SUFFIX = ".tlog"
_TIMESTAMP = struct.Struct(">Q")   # pymavlink mavutil.mavlogfile: struct.pack('>Q', int(time.time() * 1e6))


class TlogLog(RotatingLog):
    prefix = TLOG_PREFIX
    suffix = TLOG_SUFFIX
    format_name = "mavlink-tlog"

    def put(self, entry) -> bool:
        """`entry`: the frame's bytes (stamped with the wall clock now) or `(unix_s, frame_bytes)`."""
        if isinstance(entry, (bytes, bytearray, memoryview)):
            entry = (self._clock(), bytes(entry))
        return super().put(entry)

    def _open(self, path: Path):
        return open(path, "wb")

    def _write_block(self, file, entries: list) -> None:
        pack = _TIMESTAMP.pack
        file.write(b"".join([pack(int(unix_s * 1e6)) + frame for unix_s, frame in entries]))
