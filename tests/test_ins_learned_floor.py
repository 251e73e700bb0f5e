"""The floor of a learned magnetometer's heading variance (estimator/mag_error_states.py `learned_floor_var_rad2`, the one rule both
the heading state's trust variance and the never-trusted-here test read): what no learned iron explains
(`iron_unmodelled_ut`, 1 µT by default) over the horizontal field, at most the calibration's own figure — a
precise calibration is not made worse by learning an iron on top of it. Worked by hand, not with the code."""

from __future__ import annotations

import math

import pytest

from ahrsd.estimator.ins import Ins
from ahrsd.estimator.mag_error_states import learned_floor_var_rad2

DEG = math.radians(1.0)


@pytest.mark.parametrize("cal_sigma_deg, h_ut, floor_deg", [
    (0.5, 20.0, 0.5),                          # 1 µT / 20 µT = 2.86°: the calibration's 0.5° is the floor
    (0.5, 200.0, math.degrees(1.0 / 200.0)),   # 0.29° < 0.5°: what no iron explains
    (10.0, 20.0, math.degrees(1.0 / 20.0)),    # an imprecise calibration: 2.86°
])
def test_the_learned_floor_is_the_unexplained_iron_over_the_field_at_most_the_calibrations_figure(
        cal_sigma_deg, h_ut, floor_deg):
    ins = Ins(0.0, mag_calibration_sigma_rad=cal_sigma_deg * DEG, iron_unmodelled_ut=1.0)
    assert math.sqrt(learned_floor_var_rad2(ins.params, h_ut ** 2)) == pytest.approx(floor_deg * DEG, rel=1e-12)
