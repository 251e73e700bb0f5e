"""One daemon per state directory: an exclusive flock(2) on STATE_DIR/lock, taken by `ahrsd run` before anything in
the directory is written and held for the process's life.

Two daemons on one directory would each write the calibration, the learned iron, the heading and position memory,
the parameters and the logs: the last writer wins and the state is silently mixed.

Why flock and not a PID file: the lock belongs to the open file, so the kernel drops it when the process ends, however
it ends (SIGKILL, a crash, the OOM killer, a power cut: the lock is gone after a reboot). There is no stale lock to
judge, no PID that a later process may have been given, and test-and-take is one call (two daemons started at once
cannot both win). The PID written into the file after locking is for the refusal's message only, never for deciding.
The descriptor is not inherited (O_CLOEXEC; the field fit's worker is spawned, an exec), so no child keeps the lock
after the daemon is gone. The file is never deleted: deleting it would let a third process lock a new file while the
first still holds the old one.
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

LOCK_FILE_NAME = "lock"


class StateDirBusy(Exception):
    """Another process holds the directory's lock: `pid` is the one it wrote (None when it has not yet)."""

    def __init__(self, directory: Path, pid: int | None):
        self.directory = directory
        self.pid = pid
        super().__init__(
            f"the state directory {directory} is in use by another ahrsd ({self.who}): two daemons on one "
            f"directory would overwrite each other's calibration, learned iron, position memory and logs. Stop the "
            f"other one (under systemd: systemctl stop ahrsd), or give this one its own directory with --state-dir DIR")

    @property
    def who(self) -> str:
        """The holder as a message names it."""
        return f"PID {self.pid}" if self.pid is not None else "its PID not yet written"


class StateDirLock:
    """The held lock (`acquire`); `release` at the end of the run (the kernel releases it anyway at exit)."""

    def __init__(self, fd: int, path: Path):
        self._fd: int | None = fd
        self.path = path

    @classmethod
    def acquire(cls, state_dir: Path) -> StateDirLock:
        """Lock STATE_DIR/lock (creating the directory and the file) and write this process's PID into it.
        StateDirBusy when another process holds it; OSError when the directory or the file cannot be had."""
        state_dir = Path(state_dir)
        state_dir.mkdir(parents=True, exist_ok=True)
        path = state_dir / LOCK_FILE_NAME
        # no O_TRUNC: the holder's PID must survive a refused open, for the message
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            pid = _read_pid(fd)
            os.close(fd)
            raise StateDirBusy(state_dir, pid) from None
        except OSError:
            os.close(fd)
            raise
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        return cls(fd, path)

    def release(self) -> None:
        """Empty the file (no PID left that names a process gone) and drop the lock."""
        if self._fd is None:
            return
        try:
            os.ftruncate(self._fd, 0)
        except OSError:
            pass
        os.close(self._fd)
        self._fd = None


def holder(state_dir: Path) -> StateDirBusy | None:
    """Who holds `state_dir`'s lock (StateDirBusy, not raised), or None when nobody does — without creating or
    writing anything (an offline writer's check, cli/calibrate.py): no lock file means no daemon ever ran there."""
    try:
        fd = os.open(Path(state_dir) / LOCK_FILE_NAME, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)   # conflicts with the daemon's exclusive lock only
    except BlockingIOError:
        return StateDirBusy(Path(state_dir), _read_pid(fd))
    except OSError:
        return None
    finally:
        os.close(fd)                                     # drops a shared lock taken here
    return None


def _read_pid(fd: int) -> int | None:
    try:
        text = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None
