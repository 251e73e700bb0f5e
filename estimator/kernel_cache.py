"""Numba's on-disk cache for the compiled kernels, in a directory named by a digest of their whole source.

Numba's cache (`cache=True`) checks only the file of the decorated function: a cached `ins_step` or
`mekf_step` keeps the code of a helper it calls from another module (mag_heading, kernel_rotations,
constrained_update, gsf_yaw, …) after that helper's body changes, until its own file changes (numba's pull
requests #8396 and #9563 to extend the check to other files were not merged). A partial update, or an edit
to a helper, would then run the old code. So the cache lives in `<base>/ahrsd-kernels-<digest>`, the digest
over the sources of this package and of `core` (whose flag values the kernels freeze in): any change starts
an empty cache (one compile), never a stale one. `<base>` is NUMBA_CACHE_DIR when set (the systemd unit sets
it), else this package's `__pycache__`. Directories of older sources are left behind (a few MB each).

`use_source_keyed_cache()` runs in `estimator/__init__.py`, before any kernel module is imported (numba
reads the cache directory when a kernel is decorated)."""

from __future__ import annotations

import hashlib
import os
import sys
from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent
_SOURCES = (_PACKAGE, _PACKAGE.parent / "core")
PREFIX = "ahrsd-kernels-"


def source_digest() -> str:
    """A digest of every .py file of this package and of core (names and contents)."""
    h = hashlib.sha256()
    for folder in _SOURCES:
        for path in sorted(folder.glob("*.py")):
            h.update(f"{folder.name}/{path.name}\0".encode())
            h.update(path.read_bytes())
    return h.hexdigest()[:16]


def use_source_keyed_cache() -> str:
    """Point numba's cache at the directory of the current sources; returns it."""
    numba = sys.modules.get("numba")
    base = (numba.config.CACHE_DIR if numba is not None else os.environ.get("NUMBA_CACHE_DIR")) or \
        str(_PACKAGE / "__pycache__")
    if os.path.basename(os.path.normpath(base)).startswith(PREFIX):   # inherited from a parent process
        base = os.path.dirname(os.path.normpath(base))
    path = os.path.join(base, PREFIX + source_digest())
    if numba is not None:
        numba.config.CACHE_DIR = path
    else:
        os.environ["NUMBA_CACHE_DIR"] = path   # numba reads it when it is first imported
    return path
