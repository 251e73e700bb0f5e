"""A log that never delays its caller: entries go through a bounded queue to a writer thread, which writes them
to files that rotate by size and age, keeps the directory's total under a cap (oldest files deleted first),
and stops with one warning on a full disk or a read-only filesystem.

The hand-off is batched: `put()` appends to a deque (thread-safe, no lock, no wake-up) and the writer wakes
every `batch_interval_s` (0.5 s) to take everything queued and write it a block at a time. Waking the writer per
entry (a queue.Queue's condition variable) cost a context switch and a GIL hand-off per entry, several times
the writing itself at 819.2 entries/s.

Each file has a JSON sidecar (`<file>.json`, written atomically when the file opens and again when it closes)
saying what is in it: the format, the wall-clock time of its first entry, how to map entry times to UTC, the
metadata the caller gave (e.g. the calibration in force), and, once closed, the counts. A subclass says how a
file is opened and how a block of entries is written (`SampleLog`: recordings as .csv.gz; `TlogLog`: MAVLink
.tlog).
"""

from __future__ import annotations

import collections
import errno
import json
import logging
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger(__name__)

SIDECAR_SUFFIX = ".json"
_STOP = object()
_ROTATE = object()
# entries formatted between two writes to the file. A write (zlib, the kernel) releases the GIL; between two,
# the writer holds it and a reader wake that falls there waits (CPython hands the GIL over on request only
# after sys.getswitchinterval(), 5 ms). 32 rows keep that hold well inside the 1.22 ms sample period (the
# writer's cost per row: docs/logging.md).
_CHUNK_ENTRIES = 32


@dataclass(frozen=True)
class LogLimits:
    """Rotation and retention. Defaults: a file per hour or 64 MB, at most 1 GB in the directory."""

    max_file_bytes: int = 64 * 1024 * 1024     # start a new file once the current one is this large
    max_file_age_s: float = 3600.0             # ... or this old (s of wall-clock time)
    max_total_bytes: int = 1024 * 1024 * 1024  # delete the oldest files (of this log's kind) beyond this
    queue_entries: int = 65536                 # entries waiting for the writer; more are dropped and counted
    flush_interval_s: float = 1.0              # flushed this often: a crash loses at most this + batch_interval_s
    flush_entries: int = 8192                  # ... and flush (and check the size) this often too
    # the writer takes what is queued this often. Each wake starts on cold caches, so fewer wakes cost less CPU
    # per sample, up to this interval and no further beyond (docs/logging.md, bench/log_size.py --paced)
    batch_interval_s: float = 0.5

    def __post_init__(self):
        if self.max_file_bytes <= 0 or self.max_file_age_s <= 0 or self.max_total_bytes <= 0:
            raise ValueError(f"log limits must be positive: {self}")
        if (self.queue_entries < 1 or self.flush_interval_s <= 0 or self.flush_entries < 1
                or self.batch_interval_s <= 0):
            raise ValueError(f"queue_entries and flush_entries must be ≥ 1, flush_interval_s and batch_interval_s "
                             f"> 0: {self}")


class RotatingLog:
    """Base class. `put(entry)` never blocks: the entry is queued, or dropped and counted when the queue is full
    or the log has stopped. `close()` writes everything queued and closes the file. `put`, `set_metadata` and
    `close` are for one caller thread (the service's event loop).

    Subclasses set `prefix` and `suffix` (file name: `<prefix>-YYYYmmddTHHMMSS.ffffffZ<suffix>`, UTC, so names
    sort by time) and `format_name`, and implement `_open(path) -> file`, `_write_block(file, entries)` and
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
        # deque.append/popleft are atomic in CPython: the caller appends, the writer pops, no lock between them
        self._queue: collections.deque = collections.deque()
        self._wake = threading.Event()     # close() wakes the writer at once; otherwise it wakes on its interval
        self.written = 0            # entries written
        self._dropped_at_put = 0    # entries refused by put(): queue full, or the log stopped
        self._dropped_unwritten = 0  # entries queued before the log stopped, never written
        self.files_opened = 0
        self.files_deleted = 0
        self.writer_cpu_s = 0.0     # CPU time of the writer thread so far (what logging costs besides put())
        self.failure: str | None = None   # why the log stopped (e.g. "No space left on device"), None while OK
        self._stopped = threading.Event()
        self._file = None
        self._path: Path | None = None
        self._sidecar: dict = {}
        self._unflushed = False
        self._thread = threading.Thread(target=self._run, name=f"{self.prefix}-log", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------------------------------ caller side
    def put(self, entry) -> bool:
        """Queue one entry; False (and counted in `dropped`) when it cannot be kept."""
        q = self._queue
        if self.failure is not None or self._stopped.is_set() or len(q) >= self.limits.queue_entries:
            self._dropped_at_put += 1
            return False
        q.append(entry)
        return True

    def set_metadata(self, **metadata) -> None:
        """Change what the sidecar says (e.g. a new calibration in force) from the next entry on: the current
        file is closed and a new one starts, so each file has one set of metadata."""
        self._queue.append((_ROTATE, dict(metadata)))   # in order with the entries; never refused

    @property
    def dropped(self) -> int:
        """Entries given to put() that were not written: the queue was full, or the log had stopped."""
        return self._dropped_at_put + self._dropped_unwritten

    @property
    def queued(self) -> int:
        """Entries (and metadata changes) waiting for the writer."""
        return len(self._queue)

    @property
    def counters(self) -> dict:
        return {"written": self.written, "dropped": self.dropped, "files_opened": self.files_opened,
                "files_deleted": self.files_deleted, "queued": self.queued, "failure": self.failure,
                "writer_cpu_s": round(self.writer_cpu_s, 3)}

    @property
    def current_path(self) -> Path | None:
        return self._path

    def close(self, timeout_s: float = 10.0) -> None:
        if self._stopped.is_set():
            return
        self._stopped.set()
        self._queue.append(_STOP)
        self._wake.set()
        self._thread.join(timeout_s)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------------------------------ subclass side
    def _open(self, path: Path):
        raise NotImplementedError

    def _write_block(self, file, entries: list) -> None:
        """Write `entries` (a list, in order) to `file`; an OSError means none of them counts as written."""
        raise NotImplementedError

    def _entry_time_s(self, entry) -> float | None:
        return None

    def _flush(self, file) -> None:
        file.flush()

    def _size_bytes(self, file, path: Path) -> int:
        return path.stat().st_size

    # ------------------------------------------------------------------------------------------ writer thread
    def _run(self) -> None:
        limits = self.limits
        wait_s = min(limits.batch_interval_s, limits.flush_interval_s)
        next_flush = time.monotonic() + limits.flush_interval_s
        q = self._queue
        stop = False
        while not stop:
            self._wake.wait(wait_s)
            block = [q.popleft() for _ in range(len(q))]
            entries: list = []
            for item in block:
                if item is _STOP or (type(item) is tuple and item and item[0] is _ROTATE):
                    self._write_entries(entries)
                    entries = []
                    if item is _STOP:
                        stop = True
                        continue       # anything after it came from a put() racing close(): counted below
                    self._apply_metadata(item[1])
                elif stop:
                    self._dropped_unwritten += 1
                else:
                    entries.append(item)
            self._write_entries(entries)
            now = time.monotonic()
            if now >= next_flush:
                next_flush = now + limits.flush_interval_s
                self._guarded(self._flush_and_check)
            self.writer_cpu_s = time.thread_time()
        self._guarded(self._close_file)
        self.writer_cpu_s = time.thread_time()

    def _guarded(self, action, *args) -> bool:
        """Run a file operation; an OSError stops the log (one warning). False once the log has stopped."""
        if self.failure is not None:
            return False
        try:
            action(*args)
            return True
        except OSError as exc:
            self._fail(exc)
            return False

    def _apply_metadata(self, metadata: dict) -> None:
        if self.failure is None:
            self._metadata.update(metadata)
            self._guarded(self._close_file)

    def _write_entries(self, entries: list) -> None:
        """Write entries in chunks that end where the file is due a flush (every flush_entries of its entries)."""
        k, n = 0, len(entries)
        while k < n:
            if self.failure is not None:   # stopped: count what is left, write nothing
                self._dropped_unwritten += n - k
                return
            if self._file is not None and self._clock() - self._opened_wall >= self.limits.max_file_age_s:
                if not self._guarded(self._close_file):   # a file never holds (much) more than its span
                    continue
            if self._file is None and not self._guarded(self._open_file, entries[k]):
                continue
            room = self.limits.flush_entries - self._sidecar["entries"] % self.limits.flush_entries
            chunk = entries[k:k + min(room, _CHUNK_ENTRIES)]
            if not self._guarded(self._write_block, self._file, chunk):
                continue                  # the chunk is counted as dropped by the next turn
            k += len(chunk)
            self.written += len(chunk)
            self._unflushed = True
            side = self._sidecar
            side["entries"] += len(chunk)
            if "t_first_s" not in side:
                t_first = next((t for t in map(self._entry_time_s, chunk) if t is not None), None)
                if t_first is not None:
                    side["t_first_s"] = t_first
            t_last = self._entry_time_s(chunk[-1])
            if t_last is not None:
                side["t_last_s"] = t_last
            if side["entries"] % self.limits.flush_entries == 0:
                self._guarded(self._flush_and_check)

    def _flush_and_check(self) -> None:
        """Flush what was written, then start a new file if this one has reached its size."""
        if self._file is None or not self._unflushed:
            return
        self._flush(self._file)
        self._unflushed = False
        if self._size_bytes(self._file, self._path) >= self.limits.max_file_bytes:
            self._close_file()

    def _open_file(self, entry) -> None:
        self.directory.mkdir(parents=True, exist_ok=True)
        wall = self._clock()
        t = self._entry_time_s(entry)
        offset = None       # entry times are a monotonic clock: this maps them to wall-clock time
        if self._unix_minus_t is not None:
            offset = self._unix_minus_t()
        elif t is not None:
            offset = wall - t
        named = wall if offset is None or t is None else t + offset   # named after its first entry's time
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
