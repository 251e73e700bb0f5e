"""The slewed yaw's step compiled (numba): slewed_yaw.slew_step, the same source (YawSlew.step's, which has the
rule and why) compiled as it is, for ins's published heading, which steps it at every sample, inside its compiled
run of a block's samples too (published_heading.published_offset_step, ins_step_block.py). slewed_yaw.py itself
stays free of numba: the field fit's worker imports it through the daemon's parts and must not load numba
(tests/test_daemon_imports.py)."""

from __future__ import annotations

from numba import njit

from . import slewed_yaw

slew_step = njit(cache=True)(slewed_yaw.slew_step)
