"""bench/heading_timeline.py `--late S`: the figures over a long run's last part (issue 28's runs are up to 900 s; does
the error grow after 600 s?). The truth is written here by hand, not computed by the bench."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.heading_timeline import figures_from, main


def test_the_late_figures_count_the_samples_from_the_given_second_on():
    t_s = np.array([0.0, 10.0, 20.0, 30.0])
    heading_err_deg = np.array([5.0, -1.0, 2.0, -2.0])
    tilt_err_deg = np.array([1.0, 0.3, 0.4, 0.0])
    sigma_yaw_deg = np.array([1.0, 1.0, 0.5, 1.0])
    heading, tilt, sigma, beyond = figures_from(t_s, heading_err_deg, tilt_err_deg, sigma_yaw_deg, 10.0)
    # from 10 s: heading −1, 2, −2 → √(9/3); tilt 0.3, 0.4, 0 → √(0.25/3); σ 1, 0.5, 1 → 1; only 2 > 3 × 0.5
    assert heading == pytest.approx(math.sqrt(3.0))
    assert tilt == pytest.approx(math.sqrt(0.25 / 3.0))
    assert sigma == pytest.approx(1.0)
    assert beyond == pytest.approx(1.0 / 3.0)
    assert all(math.isnan(v) for v in figures_from(t_s, heading_err_deg, tilt_err_deg, sigma_yaw_deg, 31.0))


@pytest.mark.parametrize("late", ["600", "-1"])
def test_a_late_start_outside_the_run_is_a_usage_error_before_any_run(late):
    with pytest.raises(SystemExit) as exc:
        main(["--seconds", "600" if late == "-1" else "300", "--late", late, "--seeds", "11"])
    assert exc.value.code == 2
