"""Ins loads the compiled kernels it calls from Python at construction, not at their first call: the first
call types the arguments and loads the machine code from numba's cache (milliseconds each), which in the daemon
would fall on its event loop at the first fix, heading check and yaw alignment. A fresh interpreter, so that
nothing else has loaded them before."""

from __future__ import annotations

import json
import subprocess
import sys

_SCRIPT = r"""
import json, math
import numba.core.dispatcher as dispatcher
from ahrsd.estimator.ins import Ins
from bench.vehicle_accuracy import HONESTY_SITES, estimates_in_arrival_order, simulate_vehicle

site, iron = HONESTY_SITES["held-out"]
run = simulate_vehicle("car", 20.0, 14, site, mag="uncalibrated", iron=iron)
est = Ins(declination_rad=run.declination_rad, lever_arm_m=run.lever_arm_m,
          mag_calibration_sigma_rad=run.mag_calibration_sigma_rad)
loaded = []
compile_for_args = dispatcher.Dispatcher._compile_for_args


def counted(self, *args, **kws):
    loaded.append(self.py_func.__name__)
    return compile_for_args(self, *args, **kws)


dispatcher.Dispatcher._compile_for_args = counted
for _ in estimates_in_arrival_order(est, run, run.fixes):
    pass
print(json.dumps({"loaded_in_run": loaded, "alignments": est.gnss_yaw_alignments,
                  "checks": len(est.heading_checks)}))
"""


def test_no_kernel_is_loaded_after_construction_through_a_gnss_yaw_alignment():
    """The held-out car from start-up through its first fixes, heading checks and the alignment to the GNSS yaw
    (a yaw reset: attitude, history and velocity corrected): numba's dispatcher compiles (or loads) nothing after
    `Ins()`. Broken (the loading at construction dropped): fuse_gnss, the GNSS yaw bank's kernels, the history
    corrections and fill_outputs are loaded in the run."""
    out = subprocess.run([sys.executable, "-c", _SCRIPT], capture_output=True, text=True, timeout=600, check=True)
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result["alignments"] == 1 and result["checks"] > 10      # the paths were taken
    assert result["loaded_in_run"] == []


def test_argument_types_are_numbas_own_for_every_array_kind():
    """kernel_entry.argument_types looks an array's numba type up once per process: it must still be exactly what
    numba's typeof gives for each array, after another array of the same dtype but another layout, read-only flag
    or class has been typed first (the first seen of each is cached). Compared with `typeof_pyval` of each array,
    called directly. Broken (the read-only flag or the contiguity dropped from the look-up key): the second array
    gets the first one's type. (numba types a recarray as the ndarray it views: the class in the key costs nothing.)"""
    import numpy as np

    from ahrsd.estimator import ins_core as core
    from ahrsd.estimator.kernel_entry import argument_types

    kernel = core.fuse_gnss
    state = np.zeros(1, core.INS_STATE_DTYPE)
    read_only = state.copy()
    read_only.flags.writeable = False
    matrix = np.zeros((4, 3))
    strided = np.zeros((4, 6))[:, ::2]
    args = (state, read_only, state.view(np.recarray), matrix, np.asfortranarray(matrix), strided, 1.0, 2, True,
            matrix[0], np.zeros(3, np.float32))
    for order in (args, args[::-1]):
        assert argument_types(kernel, order) == tuple(kernel.typeof_pyval(a) for a in order)
