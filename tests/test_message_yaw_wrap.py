"""ATTITUDE and VISION_POSITION_ESTIMATE send the true heading wrapped to [−π, π) (common.xml: yaw in rad, −π..π),
with the float arithmetic (core.angles.wrap_pi_float) instead of numpy's ufunc on one scalar (docs/daemon.md
"Session 42 (spicpu)": the ufunc was most of the build on a cold wake). Both must send the same bits as before:
the truth here is numpy's `np.mod(yaw + π, 2π) − π`, which the builders used until session 42, written out, and the
wrapped angle's distance to the true heading from math.remainder (an independent rounding: within 1e-12 rad)."""

from __future__ import annotations

import math
import struct

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from ahrsd.daemon import messages as msgs


class _Est:
    def __init__(self, yaw_rad: float):
        self.roll_rad, self.pitch_rad = 0.1, -0.2
        self.heading_true_rad = yaw_rad
        self.rate_body_rad_s = np.array([0.01, 0.02, 0.03])
        self.sigma_rpy_rad = np.array([0.01, 0.01, 0.05])


def _numpy_wrap(yaw_rad: float) -> float:
    return float(np.mod(np.float64(yaw_rad) + np.pi, 2.0 * np.pi) - np.pi)


def _bits(x: float) -> bytes:
    return struct.pack("<d", x)


@settings(derandomize=True, max_examples=300, deadline=None)
@given(st.one_of(st.floats(-100.0, 100.0, allow_nan=False),
                 st.sampled_from([math.pi, -math.pi, 0.0, -0.0, 2 * math.pi, -2 * math.pi, 3 * math.pi])))
def test_attitude_and_vpe_send_the_wrapped_yaw_bit_for_bit(yaw_rad):
    est = _Est(yaw_rad)
    sent = (msgs.attitude(est, 1, yaw_rad).yaw, msgs.vision_position_estimate(est, 1, yaw_rad, 0).yaw)
    want = _numpy_wrap(yaw_rad)
    for yaw in sent:
        assert type(yaw) is float
        assert _bits(yaw) == _bits(want)
        assert -math.pi <= yaw < math.pi
        assert abs(math.remainder(yaw - yaw_rad, 2 * math.pi)) < 1e-12


def test_a_heading_of_pi_is_sent_as_minus_pi():
    # worked: (π + π) mod 2π = 0, minus π
    assert msgs.attitude(_Est(math.pi), 1, math.pi).yaw == -math.pi
    assert msgs.attitude(_Est(3.5), 1, 3.5).yaw == 3.5 - 2 * math.pi
