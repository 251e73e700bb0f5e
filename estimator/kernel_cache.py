"""Numba's on-disk cache for the compiled kernels, in a directory named by a digest of their whole source.

Numba's cache (`cache=True`) checks only the file of the decorated function: a cached `ins_step` or
`mekf_step` keeps the code of a helper it calls from another module (mag_heading, kernel_rotations,
constrained_update, gsf_yaw, …) after that helper's body changes, until its own file changes (numba's pull
requests #8396 and #9563 to extend the check to other files were not merged). A partial update, or an edit
to a helper, would then run the old code. So the cache lives in `<base>/ahrsd-kernels-<digest>`, the digest
over the sources of the kernels (and of what they freeze in, e.g. core's flag values): any change starts
an empty cache (one compile), never a stale one. Only what the kernels are compiled from is digested: the modules
that import numba and, transitively, the ahrsd modules they import names from (core's flags and gravity, the
rotations' constants); a name used only as a Python base class (`SmoothingIns(Ins)`) is not followed, since no
kernel can compile a class. An edit of the Python around the kernels (`mekf.py`, `ins.py`, core's config, the
CLI) keeps the cache. `<base>` is NUMBA_CACHE_DIR when set (the systemd unit sets it), else this package's
`__pycache__`.

Each upgrade (and each edit in a checkout) leaves the directory of the older sources behind, so the sibling
directories of other digests are pruned, and only when no process can be using them:
* a process that uses a cache directory holds a shared `flock` on its `in-use.lock` for its whole life (the
  kernel drops it when the process ends, however it ends), so a daemon of another version that runs on the
  same machine keeps its cache: a sibling is removed only by whoever gets the lock exclusively;
* and only when nothing in it was touched for `STALE_AFTER_S` (the lock file's time is renewed at every
  start): a process that has made the directory but not yet locked it, or a version older than this lock,
  is not raced. Were such a directory removed under a running process anyway, numba makes it again on its
  next save (`ensure_cache_path`); the loaded kernels live in memory.
A sibling is renamed before it is removed, so a process starting on it at that moment makes a fresh one.

`use_source_keyed_cache()` runs in `estimator/__init__.py`, before any kernel module is imported (numba
reads the cache directory when a kernel is decorated)."""

from __future__ import annotations

import ast
import fcntl
import hashlib
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent
_ROOT = _PACKAGE.parent    # the ahrsd namespace: its top-level folders are ahrsd.core, ahrsd.estimator, ...
PREFIX = "ahrsd-kernels-"
LOCK_NAME = "in-use.lock"
MEMO_NAME = "kernel-sources.json"   # kernel_sources' parse results, in this package's __pycache__
# a sibling untouched this long is no one's cache being set up; a cache that is in use holds its lock anyway
STALE_AFTER_S = 14 * 86400.0

_held_locks: dict[str, int] = {}    # cache directory → the open lock file this process holds shared


def _imports_numba(tree: ast.Module) -> bool:
    return any(isinstance(n, ast.Import) and any(a.name.split(".")[0] == "numba" for a in n.names)
               or isinstance(n, ast.ImportFrom) and n.level == 0 and (n.module or "").split(".")[0] == "numba"
               for n in ast.walk(tree))


def _import_candidates(path: Path, tree: ast.Module) -> list[Path]:
    """The ahrsd source files `path` may import names from (relative imports and `ahrsd.…`; the ones that exist
    are the imported sources), at any depth of the module, leaving out imports whose names are used only as the
    bases of Python classes."""
    bases: set[int] = set()
    names_seen: list[ast.Name] = []
    imports: list[ast.ImportFrom] = []
    for n in ast.walk(tree):          # one walk
        if isinstance(n, ast.Name):
            names_seen.append(n)
        elif isinstance(n, ast.ClassDef):
            bases.update(id(b) for b in n.bases)
        elif isinstance(n, ast.ImportFrom) and (n.level or (n.module or "").startswith("ahrsd.")):
            imports.append(n)
    used = {n.id for n in names_seen if id(n) not in bases}
    found: list[Path] = []
    for n in imports:
        names = [a.asname or a.name for a in n.names]
        if not any(name in used for name in names):
            continue
        parts = (n.module or "").split(".")[1:] if n.level == 0 else [m for m in (n.module or "").split(".") if m]
        folder = (_ROOT if n.level == 0 else path.parents[n.level - 1]).joinpath(*parts)
        found += [folder.with_suffix(".py")] if parts else []
        found += [folder / f"{a.name}.py" for a in n.names]   # `from . import mag_heading`
    return found


def _read_memo() -> dict:
    try:
        memo = json.loads((_PACKAGE / "__pycache__" / MEMO_NAME).read_bytes())
    except (OSError, ValueError):
        return {}
    return memo if isinstance(memo, dict) else {}


def _write_memo(memo: dict) -> None:
    """Atomically (processes start side by side); a package directory this process cannot write keeps none."""
    folder = _PACKAGE / "__pycache__"
    try:
        folder.mkdir(exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=MEMO_NAME, dir=folder)
        with os.fdopen(fd, "w") as fh:
            json.dump(memo, fh)
        os.replace(tmp, folder / MEMO_NAME)
    except OSError:
        pass


def kernel_sources() -> list[Path]:
    """The source files the compiled kernels are made from: this package's modules that import numba, and
    what they import names from, transitively."""
    return list(_kernel_source_hashes())


def source_digest() -> str:
    """A digest of the kernels' source files (names and contents: the SHA-256 of each file's contents, taken
    once by `_kernel_source_hashes`)."""
    h = hashlib.sha256()
    for path, sha in _kernel_source_hashes().items():
        h.update(f"{path.parent.name}/{path.name}\0{sha}\0".encode())
    return h.hexdigest()[:16]


def _kernel_source_hashes() -> dict[Path, str]:
    """`kernel_sources` in order, each with the SHA-256 (hex) of its contents: every file is read and hashed once.

    Parsing is what costs, and every process start computes this (the daemon, its reader process, each CLI
    run): what a file's parse gave (does it import numba, which files may it import from) is kept in
    `__pycache__/MEMO_NAME` under the file's path and the SHA-256 of its contents, so only a file whose
    contents changed is parsed again. Whether an imported file exists is looked up every time."""
    memo, used = _read_memo(), {}
    package = {p: p.read_bytes() for p in _PACKAGE.glob("*.py")}

    def parsed(path: Path) -> list:
        key = os.path.relpath(path, _ROOT)
        if key in used:
            return used[key]
        src = package[path] if path in package else path.read_bytes()
        sha = hashlib.sha256(src).hexdigest()
        entry = memo.get(key)
        if not (isinstance(entry, list) and len(entry) == 3 and entry[0] == sha):
            tree = ast.parse(src)
            entry = [sha, _imports_numba(tree), [os.path.relpath(c, _ROOT) for c in _import_candidates(path, tree)]]
        used[key] = entry
        return entry

    # only a file that names numba can import it
    todo = [p for p, src in package.items() if b"numba" in src and parsed(p)[1]]
    seen: set[Path] = set()
    while todo:
        path = todo.pop()
        if path not in seen:
            seen.add(path)
            todo += [c for c in (_ROOT / name for name in parsed(path)[2]) if c.is_file()]
    if used != memo:
        _write_memo(used)
    return {path: parsed(path)[0] for path in sorted(seen)}


def use_source_keyed_cache() -> str:
    """Point numba's cache at the directory of the current sources, claim it for this process and prune the
    stale caches of other sources beside it; returns it. A cache base this process cannot write (a read-only
    install) is used as it is: claiming and pruning are skipped."""
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
    try:
        claim_cache_dir(path)
        prune_stale_caches(base, keep=os.path.basename(path), now_s=time.time())
    except OSError:
        pass
    return path


def claim_cache_dir(path: str) -> None:
    """Make `path` and hold a shared lock on its lock file until this process ends (once per process);
    renews the lock file's time (the directory's last use)."""
    if path in _held_locks:
        return
    lock = os.path.join(path, LOCK_NAME)
    while True:
        os.makedirs(path, exist_ok=True)
        fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_SH)
            try:
                same = os.path.samestat(os.fstat(fd), os.stat(lock))
            except FileNotFoundError:
                same = False
            if same:       # not renamed away by a pruner between the open and the lock
                os.utime(fd)
                _held_locks[path] = fd
                return
        except BaseException:
            os.close(fd)
            raise
        os.close(fd)


def last_used_s(path: str) -> float:
    """The latest modification time of the directory `path` and of anything in it (seconds since the epoch)."""
    latest = os.stat(path).st_mtime
    for root, dirs, files in os.walk(path):
        for name in dirs + files:
            try:
                latest = max(latest, os.stat(os.path.join(root, name), follow_symlinks=False).st_mtime)
            except FileNotFoundError:
                pass
    return latest


def prune_stale_caches(base: str, *, keep: str, now_s: float, stale_after_s: float = STALE_AFTER_S) -> list[str]:
    """Remove the `PREFIX*` directories in `base` other than `keep` that no process holds (their lock file
    can be taken exclusively) and in which nothing changed for `stale_after_s` before `now_s`. Returns the
    names removed. Anything that cannot be checked or removed is left as it is."""
    removed = []
    for name in sorted(os.listdir(base)):
        path = os.path.join(base, name)
        if name == keep or not name.startswith(PREFIX) or os.path.islink(path) or not os.path.isdir(path):
            continue
        lock = os.path.join(path, LOCK_NAME)
        try:
            if now_s - last_used_s(path) < stale_after_s:
                continue
            try:
                fd, made_lock = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o644), True
            except FileExistsError:
                fd, made_lock = os.open(lock, os.O_RDWR | os.O_CLOEXEC), False
        except OSError:
            continue
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                continue        # a process is using it
            # a process that claimed it since the first look (and has ended) renewed the lock file's time
            if not made_lock and now_s - os.fstat(fd).st_mtime < stale_after_s:
                continue
            doomed = f"{path}.removing-{os.getpid()}"
            os.rename(path, doomed)
        except OSError:
            continue
        finally:
            os.close(fd)
        shutil.rmtree(doomed, ignore_errors=True)
        removed.append(name)
    return removed
