"""The GNSS-aided heading is the accelerometer axes' heading (estimator/accel_axes_heading.py), checked against
the simulator's truth: a car with ideal sensors and GNSS but for the accelerometer's x axis leaning towards y
by m_xy. In its turns the centripetal force a_c along body y reads a_c·m_xy along x, which is what a yaw error of
m_xy gives: the heading settles about m_xy off and stays (the filter has no state for it), so the published σ
must carry m_xy (InsParams.accel_axes_heading_sigma_rad, the sensor's misalignment 1σ)."""

import math

import numpy as np
import pytest

from ahrsd.core.sample import SampleFlags, make_sample
from ahrsd.estimator.accel_axes_heading import accel_axes_heading_variance_rad2
from ahrsd.estimator.ins import Ins
from ahrsd.simulation import SensorErrors

from ins_truth import DECLINATION, gnss_fixes, simulated_run, tilt_heading_errors_deg, with_fixes_offered

M_XY_RAD = math.radians(1.0)      # a deliberately bad accelerometer, so the effect stands out of the noise
SECONDS = 150.0
FROM_S = 60.0                     # after the car's first turns (90° at 28-36 s, −90° at 59-62 s)


def _run(m_xy_rad: float, **params):
    """Heading error (deg) and published yaw σ (deg) from FROM_S on, every 4th sample. The magnetometer is on
    and ideal, as on a calibrated vehicle: the GNSS-aided heading still settles about m_xy off (the magnetometer's
    σ floor is above the GNSS's), and without a magnetometer ins's published σ would be the GNSS yaw bank's
    floor (a few degrees), which hides what this term is for."""
    mis = np.zeros((3, 3))
    mis[0, 1] = m_xy_rad          # accel x picks up m_xy · f_y
    errors = SensorErrors.ideal().replace(accel_misalignment_rad=mis)
    run = simulated_run("car", SECONDS, rate_hz=200.0, seed=4, errors=errors)
    fixes = gnss_fixes(run.truth, sigma_pos_m=0.5, sigma_vel_m_s=0.02, seed=4)
    est = Ins(declination_rad=DECLINATION, **params)
    t = run.truth.t_s
    keep = np.flatnonzero((np.arange(len(t)) % 4 == 0) & (t >= FROM_S))
    q = np.empty((len(keep), 4))
    sig = np.empty(len(keep))
    j = 0
    for k in with_fixes_offered(t, fixes, est.update_gnss):
        # stepped: the estimate is built only where kept (estimator/estimate_view.py: building none changes none)
        view = est.step(make_sample(t[k], run.gyro[k], run.accel[k], run.mag[k], flags=SampleFlags.NEW_DATA))
        if j < len(keep) and k == keep[j]:
            e = view.snapshot()
            q[j], sig[j] = e.q_wxyz, math.degrees(e.sigma_rpy_rad[2])
            j += 1
    _, hdg = tilt_heading_errors_deg(q, run.truth.q_wxyz[keep])
    return hdg, sig


@pytest.fixture(scope="module")
def aligned():
    return _run(0.0)


@pytest.fixture(scope="module")
def leaning():
    return _run(M_XY_RAD, accel_axes_heading_sigma_rad=M_XY_RAD)


def test_the_heading_follows_the_accelerometer_axes_misalignment(aligned, leaning):
    hdg0, _ = aligned
    hdg1, _ = leaning
    # the same car and fixes with aligned axes: the heading is right to a few hundredths of a degree
    assert np.sqrt(np.mean(hdg0 ** 2)) < 0.1
    # with the x axis leaning by 1°: the heading is off by about that much, for good (the worked relation
    # δψ = m_xy of the module docstring; between turns the gyro keeps it, braking pulls towards m_yx = 0)
    # (estimate − truth, the convention of tilt_heading_errors_deg: the estimate turned towards the leaning axis)
    assert 0.7 < np.mean(hdg1) < 1.3, np.mean(hdg1)
    assert np.mean(hdg1 > 0.3) > 0.95


def test_the_published_sigma_carries_the_accelerometer_axes_misalignment(leaning):
    hdg, sig = leaning
    assert np.mean(np.abs(hdg) <= 3.0 * sig) >= 0.99
    assert np.min(sig) >= math.degrees(M_XY_RAD)     # the term is in quadrature: never below it


def test_without_the_term_the_filter_sigma_does_not_cover_it():
    hdg, sig = _run(M_XY_RAD, accel_axes_heading_sigma_rad=0.0)
    assert np.mean(np.abs(hdg) > 3.0 * sig) > 0.2


def test_worked_numbers():
    assert accel_axes_heading_variance_rad2(0.004) == pytest.approx(1.6e-5, rel=1e-12)
    assert accel_axes_heading_variance_rad2(0.0) == 0.0
    assert accel_axes_heading_variance_rad2(math.nan) == 0.0
