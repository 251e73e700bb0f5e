"""The compiled kernels' on-disk cache follows their whole source (estimator/kernel_cache.py): a change to a
helper in another module than the kernel's (numba alone checks only the kernel's own file) is compiled into
the kernel, not served stale from the cache. Counted by numba's cache hits and misses, in a copy of the
package with its own cache directory."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

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


def test_a_changed_helper_in_another_module_is_recompiled_into_the_kernel(tmp_path):
    for part in ("core", "estimator"):
        shutil.copytree(REPO / part, tmp_path / "ahrsd" / part, ignore=shutil.ignore_patterns("__pycache__"))
    hits, misses, roll = _probe(tmp_path)
    assert misses >= 1                                  # compiled into the empty cache
    hits, misses, roll_again = _probe(tmp_path)
    assert hits >= 1 and misses == 0 and roll_again == roll   # served from the cache
    # fill_euler lives in mekf_core.py; the helper it calls, euler_zyx, in kernel_rotations.py
    helper = tmp_path / "ahrsd" / "estimator" / "kernel_rotations.py"
    text = helper.read_text()
    assert text.count("    return roll, pitch, yaw\n") == 1
    helper.write_text(text.replace("    return roll, pitch, yaw\n", "    return -roll, pitch, yaw\n"))
    hits, misses, roll_changed = _probe(tmp_path)
    assert misses >= 1 and roll_changed == -roll
