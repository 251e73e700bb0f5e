"""The recording backend: a GNSS recording (recording.py's CSV format) released in step with an IMU replay.

A recorded fix is due when its time of validity is not after the newest IMU sample the replay has processed:
`replay_time_s` is that time, on the recording's time base (the IMU recording and its .gnss.csv share it). So
the aided filter sees each fix after the samples up to its time, as it would have live, whatever the replay
speed. A row that cannot be read ends the recording for this run: logged, counted, and DEVICE_ERROR in
`health()`; fixes before it were delivered.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable

from .backend import GnssBackend, GnssHealth, GnssLinkState
from .recording import iter_gnss_fixes
from ahrsd.core.gnss import GnssFix

log = logging.getLogger(__name__)


class RecordingGnssBackend(GnssBackend):
    def __init__(self, path: str | os.PathLike, replay_time_s: Callable[[], float]):
        self.path = path
        self.replay_time_s = replay_time_s
        self.description = f"GNSS recording {path}"
        self.rows = 0
        self.errors = 0
        self.finished = False
        self._error = ""
        self._fixes = None
        self._next: GnssFix | None = None

    def start(self) -> None:
        """Open the file and read its first fix: a missing file or a bad header fails the start, with its
        reason (GnssRecordingFormatError names the file and line)."""
        self._fixes = iter_gnss_fixes(self.path)
        self._next = next(self._fixes, None)
        self.finished = self._next is None

    def read(self) -> list[GnssFix]:
        now = self.replay_time_s()
        out: list[GnssFix] = []
        while self._next is not None and self._next.t_s <= now:
            out.append(self._next)
            self.rows += 1
            self._next = self._advance()
        if self._next is None and not self.finished:
            self.finished = True
            if not self._error:
                log.info("GNSS recording finished: %d fixes", self.rows)
        return out

    def _advance(self) -> GnssFix | None:
        try:
            return next(self._fixes, None)
        except Exception as exc:  # noqa: BLE001 - read() never raises; the error names file, line and column
            self.errors += 1
            self._error = str(exc)
            log.error("GNSS recording: %s; no more fixes from it", exc)
            return None

    def health(self) -> GnssHealth:
        if self._error:
            return GnssHealth(GnssLinkState.DEVICE_ERROR, f"recording unreadable: {self._error}")
        if self.rows == 0:
            return GnssHealth(GnssLinkState.WAITING, f"{self.path}: no fix due yet")
        done = " (finished)" if self.finished else ""
        return GnssHealth(GnssLinkState.OK, f"{self.path}: {self.rows} fixes{done}")

    def stats(self) -> dict[str, dict]:
        return {"recording": {"fixes": self.rows, "errors": self.errors, "finished": self.finished}}

    def close(self) -> None:
        if self._fixes is not None:
            self._fixes.close()
