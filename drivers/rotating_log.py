"""A log that never delays its caller: entries go through a bounded queue to a writer thread, which writes them
to files that rotate by size and age, keeps the directory's total under a cap (oldest files deleted first),
and stops with one warning on a full disk or a read-only filesystem.

Each file has a JSON sidecar (`<file>.json`, written atomically when the file opens and again when it closes)
saying what is in it: the format, the wall-clock time of its first entry, how to map entry times to UTC, the
metadata the caller gave (e.g. the calibration in force), and, once closed, the counts. A subclass says how a
file is opened and how one entry is written (`SampleLog`: recordings as .csv.gz; `TlogLog`: MAVLink .tlog).
"""

from __future__ import annotations

import errno
import json
import logging
import os
import queue
import threading
import time
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger(__name__)

SIDECAR_SUFFIX = ".json"
_STOP = object()
_ROTATE = object()


@dataclass(frozen=True)
class LogLimits:
    """Rotation and retention. Defaults: a file per hour or 64 MB, at most 1 GB in the directory."""

    max_file_bytes: int = 64 * 1024 * 1024     # start a new file once the current one is this large
    max_file_age_s: float = 3600.0             # ... or this old (s of wall-clock time)
    max_total_bytes: int = 1024 * 1024 * 1024  # delete the oldest files (of this log's kind) beyond this
    queue_entries: int = 65536                 # entries waiting for the writer; more are dropped and counted
    flush_interval_s: float = 1.0              # data older than this is on disk (what a crash can lose)
    flush_entries: int = 8192                  # ... and flush (and check the size and age) this often too

    def __post_init__(self):
        if self.max_file_bytes <= 0 or self.max_file_age_s <= 0 or self.max_total_bytes <= 0:
            raise ValueError(f"log limits must be positive: {self}")
        if self.queue_entries < 1 or self.flush_interval_s <= 0 or self.flush_entries < 1:
            raise ValueError(f"queue_entries and flush_entries must be ≥ 1 and flush_interval_s > 0: {self}")


class RotatingLog:
    """Base class. `put(entry)` never blocks: the entry is queued, or dropped and counted when the queue is full
    or the log has stopped. `close()` drains the queue and closes the file.

    Subclasses set `prefix` and `suffix` (file name: `<prefix>-YYYYmmddTHHMMSS.ffffffZ<suffix>`, UTC, so names
    sort by time) and `format_name`, and implement `_open(path) -> file`, `_write(file, entry)` and
    `_entry_time_s(entry)` (the entry's own time, for the sidecar's t_first_s/t_last_s).
    """

    prefix = "log"
    suffix = ".log"
    format_name = "log"

    def __init__(self, directory: str | os.PathLike, limits: LogLimits = LogLimits(), metadata: dict | None = None,
                 clock=time.time, unix_minus_t=None):
        """clock: the wall clock (Unix s) for file ages and names. unix_minus_t: a function giving Unix time
        minus the entries' own clock (for entries stamped with time.monotonic(): time.time() −
        time.monotonic()), read when a file opens, so the mapping does not depend on how far behind the
        writer is; None: the wall clock minus the first entry's time at that moment."""
        self.directory = Path(directory)
        self.limits = limits
        self._metadata = dict(metadata or {})
        self._clock = clock
        self._unix_minus_t = unix_minus_t
        self._queue: queue.Queue = queue.Queue(maxsize=limits.queue_entries)
        self.written = 0            # entries written
        self._dropped_at_put = 0    # entries refused by put(): queue full, or the log stopped
        self._dropped_unwritten = 0  # entries queued before the log stopped, never written
        self.files_opened = 0
        self.files_deleted = 0
        self.failure: str | None = None   # why the log stopped (e.g. "No space left on device"), None while OK
        self._stopped = threading.Event()
        self._pending_lock = threading.Lock()
        self._pending_metadata: dict = {}
        self._file = None
        self._path: Path | None = None
        self._sidecar: dict = {}
        self._thread = threading.Thread(target=self._run, name=f"{self.prefix}-log", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------------------------------ caller side
    def put(self, entry) -> bool:
        """Queue one entry; False (and counted in `dropped`) when it cannot be kept."""
        if self.failure is not None or self._stopped.is_set():
            self._dropped_at_put += 1
            return False
        try:
            self._queue.put_nowait(entry)
        except queue.Full:
            self._dropped_at_put += 1
            return False
        return True

    def set_metadata(self, **metadata) -> None:
        """Change what the sidecar says (e.g. a new calibration in force) from the next entry on: the current
        file is closed and a new one starts, so each file has one set of metadata."""
        try:
            self._queue.put_nowait((_ROTATE, dict(metadata)))
        except queue.Full:   # never lost: the writer applies it as soon as it looks (a queue's worth early)
            with self._pending_lock:
                self._pending_metadata.update(metadata)

    @property
    def dropped(self) -> int:
        """Entries given to put() that were not written: the queue was full, or the log had stopped."""
        return self._dropped_at_put + self._dropped_unwritten

    @property
    def counters(self) -> dict:
        return {"written": self.written, "dropped": self.dropped, "files_opened": self.files_opened,
                "files_deleted": self.files_deleted, "queued": self._queue.qsize(), "failure": self.failure}

    @property
    def current_path(self) -> Path | None:
        return self._path

    def close(self, timeout_s: float = 10.0) -> None:
        if self._stopped.is_set():
            return
        self._stopped.set()
        try:
            self._queue.put(_STOP, timeout=timeout_s)
        except queue.Full:
            pass
        self._thread.join(timeout_s)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------------------------------ subclass side
    def _open(self, path: Path):
        raise NotImplementedError

    def _write(self, file, entry) -> None:
        raise NotImplementedError

    def _entry_time_s(self, entry) -> float | None:
        return None

    def _flush(self, file) -> None:
        file.flush()

    def _size_bytes(self, file, path: Path) -> int:
        return path.stat().st_size

    # ------------------------------------------------------------------------------------------ writer thread
    def _run(self) -> None:
        next_flush = time.monotonic() + self.limits.flush_interval_s
        while True:
            try:
                item = self._queue.get(timeout=self.limits.flush_interval_s)
            except queue.Empty:
                item = None
            if item is _STOP:
                break
            if self.failure is not None:   # stopped: drain without writing so nothing waits on us
                if item is not None and not (isinstance(item, tuple) and item and item[0] is _ROTATE):
                    self._dropped_unwritten += 1
                continue
            written_before = self.written
            try:
                if self._pending_metadata:
                    with self._pending_lock:
                        pending, self._pending_metadata = self._pending_metadata, {}
                    self._metadata.update(pending)
                    self._close_file()
                if isinstance(item, tuple) and item and item[0] is _ROTATE:
                    self._metadata.update(item[1])
                    self._close_file()
                elif item is not None:
                    self._write_entry(item)
                now = time.monotonic()
                due = now >= next_flush or self._sidecar.get("entries", 0) % self.limits.flush_entries == 0
                if self._file is not None and due:
                    next_flush = now + self.limits.flush_interval_s
                    self._flush(self._file)
                    self._rotate_if_full()
            except OSError as exc:
                is_entry = item is not None and not (isinstance(item, tuple) and item and item[0] is _ROTATE)
                if is_entry and self.written == written_before:
                    self._dropped_unwritten += 1    # the entry whose write failed is counted as dropped too
                self._fail(exc)
        try:
            self._close_file()
        except OSError as exc:
            self._fail(exc)

    def _write_entry(self, entry) -> None:
        if self._file is not None and self._clock() - self._opened_wall >= self.limits.max_file_age_s:
            self._close_file()   # the age is checked per entry, so a file never holds more than its span
        if self._file is None:
            self._open_file(entry)
        self._write(self._file, entry)
        self.written += 1
        self._sidecar["entries"] += 1
        t = self._entry_time_s(entry)
        if t is not None:
            self._sidecar.setdefault("t_first_s", t)
            self._sidecar["t_last_s"] = t

    def _open_file(self, entry) -> None:
        self.directory.mkdir(parents=True, exist_ok=True)
        wall = self._clock()
        t = self._entry_time_s(entry)
        offset = None
        if t is not None:   # entry times are a monotonic clock: this maps them to wall-clock time
            offset = self._unix_minus_t() if self._unix_minus_t is not None else wall - t
        named = wall if offset is None else t + offset   # the file is named after its first entry's time
        stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime(named)) + f".{int(named % 1 * 1e6):06d}Z"
        path = self.directory / f"{self.prefix}-{stamp}{self.suffix}"
        k = 1
        while path.exists():   # never overwrite (a clock stepped back, or two files in one µs)
            path = self.directory / f"{self.prefix}-{stamp}-{k}{self.suffix}"
            k += 1
        # the sidecar first: a crash between the two then leaves a sidecar without data (ignored), never a data
        # file whose calibration and time base are unknown
        self._path = path
        self._sidecar = {"format": self.format_name, "file": path.name, "opened_utc": _iso_utc(wall),
                         "opened_unix_s": wall, "entries": 0, "closed": False, **self._metadata}
        if offset is not None:
            self._sidecar["unix_minus_t_s"] = offset
        self._write_sidecar()
        self._file = self._open(path)
        self._opened_wall = wall
        self.files_opened += 1
        self._enforce_total()

    def _rotate_if_full(self) -> None:
        if self._file is None:
            return
        if self._size_bytes(self._file, self._path) >= self.limits.max_file_bytes:
            self._close_file()

    def _close_file(self) -> None:
        if self._file is None:
            return
        file, self._file = self._file, None
        file.close()
        self._sidecar["closed"] = True
        self._sidecar["closed_utc"] = _iso_utc(self._clock())
        self._sidecar["size_bytes"] = self._path.stat().st_size
        self._write_sidecar()

    def _write_sidecar(self) -> None:
        target = self._path.with_name(self._path.name + SIDECAR_SUFFIX)
        tmp = target.with_name(f".{target.name}.tmp")
        with open(tmp, "w", encoding="utf-8") as f:
            json.dump(self._sidecar, f, indent=1, sort_keys=True)
            f.write("\n")
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, target)

    def _enforce_total(self) -> None:
        """Delete this log's oldest files (and sidecars) until the total is under the cap; never the current."""
        files = sorted(p for p in self.directory.glob(f"{self.prefix}-*{self.suffix}") if p != self._path)
        sizes = {p: _size(p) + _size(p.with_name(p.name + SIDECAR_SUFFIX)) for p in files}
        total = sum(sizes.values()) + (_size(self._path) if self._path else 0)
        for p in files:
            if total <= self.limits.max_total_bytes:
                break
            for victim in (p, p.with_name(p.name + SIDECAR_SUFFIX)):
                try:
                    victim.unlink()
                except FileNotFoundError:
                    pass
            total -= sizes[p]
            self.files_deleted += 1

    def _fail(self, exc: OSError) -> None:
        if self.failure is not None:
            return
        self.failure = exc.strerror or str(exc)
        kind = {errno.ENOSPC: "the disk is full", errno.EROFS: "the filesystem is read-only",
                errno.EDQUOT: "the disk quota is exhausted", errno.EACCES: "permission denied"}.get(exc.errno,
                                                                                             "a write failed")
        log.warning("%s log in %s stopped: %s (%s); the service keeps running without it", self.prefix,
                    self.directory, kind, self.failure)
        try:
            if self._file is not None:
                self._file.close()
        except OSError:
            pass
        self._file = None


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0


def _iso_utc(unix_s: float) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(unix_s)) + f".{int(unix_s % 1 * 1e6):06d}Z"
