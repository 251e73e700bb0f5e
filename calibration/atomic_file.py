"""Replace a small state file so that a power cut leaves either the old or the new content, never a mix:
temp file in the same directory, write, fsync, rename, fsync the directory (vehicles lose power often).

The one atomic writer of the code base: calibrations, noise files, parameters, the signing timestamp and
run statistics all go through `write_atomic`.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def fsync_dir(directory: Path) -> None:
    """Make a rename in `directory` durable (a no-op where the platform cannot open directories)."""
    try:
        fd = os.open(directory, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        return  # rename is still atomic
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def write_atomic(path: os.PathLike | str, data: bytes, *, mode: int | None = None) -> None:
    """Write `data` to `path` atomically. `mode` sets the permission bits (default: mkstemp's 0600, subject
    to nothing else; calibrations pass 0o644 so an operator can read them). The temp file is removed on error
    (e.g. ENOSPC) and the old file stays as it was."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        if mode is not None:
            os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    fsync_dir(path.parent)
