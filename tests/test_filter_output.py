"""estimator/filter_output.py: the one place an AttitudeEstimate is made from a filter's output record (mekf
and ins), checked against numbers worked by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ahrsd.core.estimate import EstimateFlags, HeadingState
from ahrsd.estimator.filter_output import AttitudeFields, attitude_estimate

# an output record as a filter lays it out, with a field before and between the attitude ones
OUT_DTYPE = np.dtype([("lat_rad", np.float64), ("q", np.float64, (4,)), ("rate_rad_s", np.float64, (3,)),
                      ("vel_ned_m_s", np.float64, (3,)), ("sigma_rpy_rad", np.float64, (3,)),
                      ("gyro_bias_rad_s", np.float64, (3,)), ("euler_rad", np.float64, (3,))])


def _record() -> np.ndarray:
    rec = np.zeros(1, OUT_DTYPE)
    rec[0]["lat_rad"] = 0.9
    rec[0]["q"] = (0.5, 0.5, -0.5, 0.5)
    rec[0]["rate_rad_s"] = (0.1, -0.2, 0.3)
    rec[0]["vel_ned_m_s"] = (7.0, 8.0, 9.0)
    rec[0]["sigma_rpy_rad"] = (0.01, 0.02, 0.05)
    rec[0]["gyro_bias_rad_s"] = (1e-3, -2e-3, 3e-3)
    rec[0]["euler_rad"] = (0.2, -0.1, -2.5)
    return rec


def test_the_fields_are_read_where_the_record_type_puts_them():
    rec = _record()
    out = rec.view(np.float64).copy()
    fields = AttitudeFields(OUT_DTYPE)
    est = attitude_estimate(12.5, out, fields, 0.2, -0.1, -2.5, -2.5 + 0.3, int(EstimateFlags.AT_REST),
                            HeadingState.MAGNETOMETER)
    assert est.t_s == 12.5
    assert est.q_wxyz.tolist() == [0.5, 0.5, -0.5, 0.5]
    assert est.rate_body_rad_s.tolist() == [0.1, -0.2, 0.3]
    assert est.gyro_bias_rad_s.tolist() == [1e-3, -2e-3, 3e-3]
    assert est.sigma_rpy_rad.tolist() == [0.01, 0.02, 0.05]
    assert (est.roll_rad, est.pitch_rad, est.yaw_rad) == (0.2, -0.1, -2.5)
    assert est.flags is EstimateFlags.AT_REST and est.heading_state is HeadingState.MAGNETOMETER
    assert est.nav is None and est.integrity is None
    # the arrays are views of the caller's fresh buffer, not copies
    assert all(np.shares_memory(a, out) for a in (est.q_wxyz, est.rate_body_rad_s, est.gyro_bias_rad_s,
                                                  est.sigma_rpy_rad))


@pytest.mark.parametrize("yaw, true, mag_deg, true_deg", [
    (-2.5, -2.5 + 0.3, 360.0 - math.degrees(2.5), 360.0 - math.degrees(2.2)),   # west of south: wrapped
    (3.0, 3.0 + 0.5, math.degrees(3.0), math.degrees(3.5)),                     # true past 180°: not wrapped
    (0.1, 0.1 - 0.3, math.degrees(0.1), 360.0 - math.degrees(0.2)),             # a west declination past north
])
def test_the_headings_are_wrapped_to_a_full_turn(yaw, true, mag_deg, true_deg):
    out = _record().view(np.float64).copy()
    est = attitude_estimate(0.0, out, AttitudeFields(OUT_DTYPE), 0.0, 0.0, yaw, true, 0, HeadingState.UNKNOWN)
    assert math.degrees(est.heading_mag_rad) == pytest.approx(mag_deg, abs=1e-9)
    assert math.degrees(est.heading_true_rad) == pytest.approx(true_deg, abs=1e-9)
    assert est.yaw_rad == yaw      # the yaw itself is handed on as the filter gave it


def test_a_record_type_without_an_attitude_field_is_refused():
    with pytest.raises(KeyError):
        AttitudeFields(np.dtype([("q", np.float64, (4,)), ("rate_rad_s", np.float64, (3,))]))
