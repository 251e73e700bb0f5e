"""Worked values of the 1980 International Gravity Formula, one home for the tests that check gravity against them
(test_simulation_environment, test_cal_accel, test_ins_mechanisation): g(L, 0) and g(L, 1000 m) in m/s² of
9.780327 (1 + 0.0053024 sin²L − 0.0000058 sin²2L) (R0/(R0+h))², R0 = 6 378 137 m, evaluated by hand."""

from __future__ import annotations

GRAVITY_WORKED_VALUES = [        # (latitude °, g at 0 m, g at 1000 m)
    (0.0, 9.780327, 9.777261),
    (30.0, 9.793249, 9.790179),
    (35.7, 9.797935, 9.794864),
    (45.0, 9.806200, 9.803126),
    (60.0, 9.819179, 9.816101),
    (90.0, 9.832186, 9.829104),
]
