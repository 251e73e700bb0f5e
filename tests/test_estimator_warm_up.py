"""The daemon compiles the estimator before its sample loop (estimator/warm_up.py): the kernels the loop calls
on a sample and on a GNSS fix are compiled (or loaded from numba's cache) by warm_up() alone."""

import subprocess
import sys

import pytest

PROBE = """
import sys
from numba.core.registry import CPUDispatcher
from ahrsd.estimator.warm_up import warm_up
from ahrsd.estimator import {module} as core
warm_up({name!r})
print(" ".join(k for k, v in vars(core).items() if isinstance(v, CPUDispatcher) and v.signatures))
"""


@pytest.mark.parametrize("name, module, kernels", [
    ("ins", "ins_core", {"input_validity", "ins_step", "fill_outputs", "fuse_gnss"}),
    ("mekf", "mekf_core", {"input_validity", "mekf_step_full", "fill_euler", "fill_outputs_after_init"}),
])
def test_warm_up_compiles_every_kernel_the_loop_calls(name, module, kernels):
    # a fresh interpreter: nothing else has called the kernels yet
    out = subprocess.run([sys.executable, "-c", PROBE.format(name=name, module=module)],
                         capture_output=True, text=True, timeout=300, check=True).stdout
    assert kernels <= set(out.split()), out
