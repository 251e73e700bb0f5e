"""The uncalibrated boat's heading at a weak horizontal field, split with the simulator's truth
(bench/heading_split.py; docs/gnss.md "The uncalibrated boat at a weak field: the vertical gyro's bias / scale split
is not the limit, its white noise is"). Tromsø (H 10.8 µT, dip 78°: the magnetometer is never trusted there),
in-sample seed 12 (nothing is chosen here), no magnetometer calibration, 300 s, heading error from 180 s against the
simulator's attitude."""

import pytest

from bench.heading_split import one_run

SECONDS = 300.0
TROMSO = "69.65,18.96"
ROWS = ("defaults", "s_z truth", "turn-on 0", "turn-on 0, no ARW", "yaw aid 1°")


@pytest.fixture(scope="module")
def runs():
    # (heading RMS, tilt RMS, beyond 3σ, b_z error RMS °/h, s_z error at the end %) per row
    return {row: one_run(("boat", 12, row, SECONDS, TROMSO))[1] for row in ROWS}


def test_the_vertical_gyro_scale_factor_is_not_what_limits_the_heading(runs):
    # told the simulator's vertical scale factor at every sample, the heading is the same: the turns of both signs
    # split it from the bias well enough
    assert runs["s_z truth"][4] == 0.0 and runs["defaults"][4] != 0.0
    assert abs(runs["defaults"][4]) < 0.25          # under half its 0.5 % prior
    assert abs(runs["s_z truth"][0] - runs["defaults"][0]) < 0.1 * runs["defaults"][0]


def test_the_gyro_white_noise_is(runs):
    # without any turn-on error the heading is no better; without the gyro's angle random walk as well it is far
    # better: between the turns the GNSS-only yaw wanders with the gyro's white noise
    assert runs["turn-on 0"][0] > 0.8 * runs["defaults"][0]
    assert runs["turn-on 0, no ARW"][0] < 0.6 * runs["turn-on 0"][0]


def test_a_heading_reference_on_the_straight_legs_would_remove_it(runs):
    heading, _, beyond, _, _ = runs["yaw aid 1°"]
    assert heading < 0.3 < runs["defaults"][0]
    assert beyond == 0.0
    for row in ROWS:
        assert runs[row][2] < 0.01, row             # σ honest in every row but the two-state oracle (not run here)
