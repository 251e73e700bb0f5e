"""The compiled kernels' on-disk cache follows their whole source (estimator/kernel_cache.py): a change to a
helper in another module than the kernel's (numba alone checks only the kernel's own file) is compiled into
the kernel, not served stale from the cache; an edit that compiles into no kernel keeps the cache. Counted by
numba's cache hits and misses, in a copy of the package with its own cache directory. The caches of other sources are pruned when stale and not held."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import pytest

from ahrsd.estimator import kernel_cache

REPO = Path(__file__).resolve().parents[1]

PROBE = """
import numpy as np
from ahrsd.estimator import mekf_core as c
euler = c.fast_fill_euler()
buf = np.zeros(1, c.MEKF_BUFFER_DTYPE)
buf[0]["out"]["q"] = np.array([0.9, 0.3, 0.2, 0.1]) / np.linalg.norm([0.9, 0.3, 0.2, 0.1])
euler(buf)
s = c.fill_euler.stats
print(sum(s.cache_hits.values()), sum(s.cache_misses.values()), buf[0]["out"]["euler_rad"][0])
"""


def _probe(root: Path) -> tuple[int, int, float]:
    env = dict(os.environ, PYTHONPATH=str(root), NUMBA_CACHE_DIR=str(root / "cache"))
    out = subprocess.run([sys.executable, "-c", PROBE], cwd=root, env=env, capture_output=True, text=True,
                         timeout=600, check=True).stdout.split()
    return int(out[0]), int(out[1]), float(out[2])


def _copy_package(root: Path) -> Path:
    for part in ("core", "estimator"):
        shutil.copytree(REPO / part, root / "ahrsd" / part, ignore=shutil.ignore_patterns("__pycache__"))
    return root / "ahrsd"


def _append_comment(path: Path) -> None:
    path.write_text(path.read_text() + "# an edit that compiles into no kernel\n")


@pytest.fixture(scope="module")
def compiled(tmp_path_factory):
    """A copy of the package with fill_euler compiled into its empty cache, and the roll the kernel gave. The
    two tests below edit this one copy (one compile fewer than a copy each): each judges what its own edit does
    to the tree and cache it finds, whichever ran first."""
    root = tmp_path_factory.mktemp("kernels")
    _copy_package(root)
    hits, misses, roll = _probe(root)
    assert misses >= 1                                  # compiled into the empty cache
    return SimpleNamespace(root=root, roll=roll)


def test_an_edit_of_the_python_around_the_kernels_keeps_the_cache(compiled):
    """Before, the cache directory's digest covered every file of estimator/ and core/, so an edit of the state
    directory rule or of the filters' Python wrappers compiled every kernel again."""
    package = compiled.root / "ahrsd"
    caches = sorted((compiled.root / "cache").glob(kernel_cache.PREFIX + "*"))
    for name in ("core/state_dir.py", "core/wmm.py", "estimator/mekf.py", "estimator/ins.py",
                 "estimator/heading_monitor.py"):
        _append_comment(package / name)
    hits, misses, roll = _probe(compiled.root)
    assert hits >= 1 and misses == 0 and roll == compiled.roll     # served from the cache
    assert sorted((compiled.root / "cache").glob(kernel_cache.PREFIX + "*")) == caches


def test_a_changed_helper_in_another_module_is_recompiled_into_the_kernel(compiled):
    # fill_euler lives in mekf_core.py; the helper it calls, euler_zyx, in kernel_rotations.py
    helper = compiled.root / "ahrsd" / "estimator" / "kernel_rotations.py"
    text = helper.read_text()
    assert text.count("    return roll, pitch, yaw\n") == 1
    helper.write_text(text.replace("    return roll, pitch, yaw\n", "    return -roll, pitch, yaw\n"))
    hits, misses, roll_changed = _probe(compiled.root)
    assert misses >= 1 and roll_changed == -compiled.roll
    compiled.roll = roll_changed


def test_the_digest_follows_every_source_a_kernel_is_compiled_from(tmp_path, monkeypatch):
    """Helpers and frozen values in other modules than the kernel's own: core's flags (kernel_flags), core's
    gravity constants (ins_mechanisation), a rotations constant (ins_smoother), a helper module (mag_heading)."""
    package = _copy_package(tmp_path)
    monkeypatch.setattr(kernel_cache, "_PACKAGE", package / "estimator")
    monkeypatch.setattr(kernel_cache, "_ROOT", package)
    digest = kernel_cache.source_digest()
    for name in ("core/estimate.py", "core/sample.py", "core/gravity.py", "estimator/rotations.py",
                 "estimator/mag_heading.py", "estimator/mekf_core.py"):
        _append_comment(package / name)
        changed = kernel_cache.source_digest()
        assert changed != digest, name
        digest = changed
    for name in ("core/state_dir.py", "estimator/ins.py", "estimator/mekf.py", "estimator/kernel_cache.py"):
        _append_comment(package / name)
        assert kernel_cache.source_digest() == digest, name



def test_the_parse_memo_follows_the_contents(tmp_path, monkeypatch):
    """kernel_sources keeps each file's parse under the SHA-256 of its contents (every process start would
    parse them again): an edit that adds an import is followed at once, and a memo that is not JSON, or whose
    entries are not the memo's, is parsed around."""
    package = _copy_package(tmp_path)
    monkeypatch.setattr(kernel_cache, "_PACKAGE", package / "estimator")
    monkeypatch.setattr(kernel_cache, "_ROOT", package)
    memo = package / "estimator" / "__pycache__" / kernel_cache.MEMO_NAME
    fresh = kernel_cache.kernel_sources()
    assert memo.is_file() and kernel_cache.kernel_sources() == fresh
    state_dir = package / "core" / "state_dir.py"
    assert state_dir not in fresh
    helper = package / "estimator" / "kernel_rotations.py"       # a kernel module, in the memo by now
    helper.write_text("from ahrsd.core.state_dir import SERVICE_STATE_DIR\n" + helper.read_text()
                      + "\n_ = SERVICE_STATE_DIR\n")
    edited = kernel_cache.kernel_sources()
    assert edited == sorted(fresh + [state_dir])
    for garbage in ("{not json", "[1, 2]", '{"estimator/kernel_rotations.py": "x"}'):
        memo.write_text(garbage)
        assert kernel_cache.kernel_sources() == edited, garbage


DAY_S = 86400.0


def _cache(base: Path, digest: str, age_days: float, now_s: float, *, lock_file: bool = True) -> Path:
    """A cache directory as numba leaves it (an index in a subfolder), everything in it last changed
    `age_days` before `now_s`."""
    d = base / (kernel_cache.PREFIX + digest)
    (d / "estimator").mkdir(parents=True)
    (d / "estimator" / "mekf_core.fill_euler-1.py312.nbi").write_bytes(b"index")
    if lock_file:
        (d / kernel_cache.LOCK_NAME).touch()
    t = now_s - age_days * DAY_S
    for p in sorted(d.rglob("*"), reverse=True) + [d]:
        os.utime(p, (t, t))
    return d


def test_stale_caches_of_other_sources_are_pruned_and_nothing_else(tmp_path):
    now_s = 2_000_000_000.0
    stale = kernel_cache.STALE_AFTER_S / DAY_S + 1.0
    current = _cache(tmp_path, "c0ffee", stale, now_s)                       # ours, however old
    old = _cache(tmp_path, "0ld0ld", stale, now_s)
    older = _cache(tmp_path, "01d3r0", 10 * stale, now_s, lock_file=False)   # left by a version without locks
    recent = _cache(tmp_path, "fe5h00", stale - 2.0, now_s)                  # used within the stale time
    touched = _cache(tmp_path, "70ched", stale, now_s)
    os.utime(touched / "estimator" / "mekf_core.fill_euler-1.py312.nbi", (now_s, now_s))  # numba saved lately
    foreign = tmp_path / "numba-something-else"
    foreign.mkdir()
    os.utime(foreign, (0.0, 0.0))
    a_file = tmp_path / (kernel_cache.PREFIX + "notadir")
    a_file.write_bytes(b"")
    os.utime(a_file, (0.0, 0.0))

    removed = kernel_cache.prune_stale_caches(str(tmp_path), keep=current.name, now_s=now_s)

    assert sorted(removed) == sorted([old.name, older.name])
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [current.name, recent.name, touched.name, foreign.name, a_file.name])


def test_a_cache_another_process_holds_is_kept_however_old(tmp_path):
    """A daemon of another version on the same machine holds its cache's lock for its whole life."""
    now_s = 2_000_000_000.0
    theirs = _cache(tmp_path, "07he45", 100.0, now_s)
    holder = subprocess.Popen(
        [sys.executable, "-c", "import fcntl, os, sys; fd = os.open(sys.argv[1], os.O_RDWR); "
         "fcntl.flock(fd, fcntl.LOCK_SH); print('held', flush=True); sys.stdin.read()",
         str(theirs / kernel_cache.LOCK_NAME)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        assert kernel_cache.prune_stale_caches(str(tmp_path), keep="ours", now_s=now_s) == []
        assert theirs.is_dir()
    finally:
        holder.stdin.close()
        holder.wait(timeout=60)
    assert kernel_cache.prune_stale_caches(str(tmp_path), keep="ours", now_s=now_s) == [theirs.name]
    assert not theirs.exists()


def test_claiming_a_cache_renews_it_and_blocks_its_pruning(tmp_path):
    now_s = time.time()
    mine = _cache(tmp_path, "m1ne00", 100.0, now_s)
    kernel_cache.claim_cache_dir(str(mine))
    try:
        assert now_s - (mine / kernel_cache.LOCK_NAME).stat().st_mtime < DAY_S     # renewed at the claim
        assert kernel_cache.prune_stale_caches(str(tmp_path), keep="other", now_s=now_s + 100 * DAY_S) == []
    finally:
        os.close(kernel_cache._held_locks.pop(str(mine)))
    assert kernel_cache.prune_stale_caches(str(tmp_path), keep="other", now_s=now_s + 100 * DAY_S) == [mine.name]
