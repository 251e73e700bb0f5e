"""A wrong heading must not teach the accelerometer bias (estimator/ins_core._gated_update,
Ins._set_accel_bias_learning):
while the heading is not known, a GNSS velocity update leaves the horizontal (body x, y) accelerometer bias alone and
moves every other error state by the ordinary Kalman gain; the `ins` holds the bias back until a GNSS yaw confirms
the heading (`accel_bias_needs_heading`, on by default), never with a trusted magnetometer or without the
GNSS yaw. Truth: the Kalman gain P·hᵀ/(h·P·hᵀ + r)
computed here with numpy."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ahrsd.estimator import ins_core as core
from ahrsd.estimator.ins import Ins
from support.gated_update import gated_velocity_update


def _gated(learn: float):
    return gated_velocity_update(learn, seed=5, velocity_axis=0, innovation_m_s=0.05)


def test_an_unknown_heading_leaves_the_horizontal_accel_bias_alone():
    dx, kalman = _gated(0.0)
    # the x and y bias, the z axis's lean the vertical channel would learn against the wrong yaw's tilt, and the x
    # and y gyros' misalignment towards z that keeps that tilt in the body (tests/test_tilt_unknown_heading.py)
    held = [core.E_BA, core.E_BA + 1, core.E_AZ_LEAN, core.E_AZ_LEAN + 1, core.E_MG + 1, core.E_MG + 3]
    assert dx[held] == pytest.approx([0.0] * 6, abs=0.0)
    others = np.setdiff1d(np.arange(core.N_ERR), held)
    assert dx[others] == pytest.approx(kalman[others], rel=1e-9, abs=1e-15)
    assert abs(dx[core.E_BA + 2]) > 0.0                # the vertical bias learns on


def test_a_known_heading_updates_every_state_by_the_kalman_gain():
    dx, kalman = _gated(1.0)
    assert dx == pytest.approx(kalman, rel=1e-9, abs=1e-15)
    assert np.all(np.abs(dx[core.E_BA:core.E_BA + 2]) > 0.0)


@pytest.mark.parametrize("calibration_sigma_deg, gnss_yaw, held", [
    (math.nan, True, True),      # no calibration: the heading is not known until a GNSS yaw confirms it
    (10.0, True, True),          # a calibration worse than the trusted 3°
    (0.5, True, False),          # a trusted calibration: the heading is known
    (math.nan, False, False),    # no GNSS yaw to confirm with: the filter before this
])
def test_the_ins_holds_the_bias_back_only_while_the_heading_is_unknown(calibration_sigma_deg, gnss_yaw, held):
    est = Ins(mag_calibration_sigma_rad=math.radians(calibration_sigma_deg), gnss_yaw=gnss_yaw,
              accel_bias_needs_heading=True)
    assert est._par["accel_bias_learn"] == (0.0 if held else 1.0)
    est._heading.confirmation.bias_heading_confirmed = True   # what a GNSS yaw within 10° does (HeadingConfirmation.confirm)
    est._heading.set_accel_bias_learning()
    assert est._par["accel_bias_learn"] == 1.0
    default = Ins(mag_calibration_sigma_rad=math.radians(calibration_sigma_deg), gnss_yaw=gnss_yaw)
    assert default._par["accel_bias_learn"] == (0.0 if held else 1.0)
    off = Ins(mag_calibration_sigma_rad=math.radians(calibration_sigma_deg), gnss_yaw=gnss_yaw,
              accel_bias_needs_heading=False)
    assert off._par["accel_bias_learn"] == 1.0


@pytest.mark.parametrize("off", [{"mag_enabled": False}, {"heading_monitor": False}, {"gnss_yaw": False}])
def test_without_the_heading_checks_nothing_can_release_the_bias_so_it_is_not_held(off):
    """The checks that confirm a heading run only with the GNSS yaw, the monitor and the magnetometer: without
    one of them the bias must learn from the start (the boat without its magnetometer, as the calibration's
    levelling runs it, kept the bias held for good and levelled 0.48° instead of 0.37°)."""
    assert Ins(**off)._par["accel_bias_learn"] == 1.0
    assert Ins()._par["accel_bias_learn"] == 0.0       # the default, no calibration: held
