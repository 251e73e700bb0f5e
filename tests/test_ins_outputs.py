"""The ins estimate carries the filter's own state: each field of the AttitudeEstimate and its NavState is
checked against the state record and the covariance it comes from (attitude through scipy, σ from the
covariance's diagonal), so an output written to or read from the wrong field fails here."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from ahrsd.core.estimate import EstimateFlags
from ahrsd.core.sample import make_sample
from ahrsd.estimator import ins_core as core
from ahrsd.estimator.accel_axes_tilt import accel_axes_tilt_variance_in_force_rad2
from ahrsd.estimator.rotations import quat_to_dcm
from ahrsd.estimator.ins import Ins

from ins_truth import DECLINATION, gnss_fixes, rot, simulated_run


def test_every_output_field_is_the_state_it_names():
    run = simulated_run("coordinated-turn", 40.0, rate_hz=200.0, seed=3)
    fixes = gnss_fixes(run.truth, seed=13)
    est = Ins(declination_rad=DECLINATION, mag_calibration_sigma_rad=math.radians(0.5))
    k = 0
    checked = 0
    for i, t in enumerate(run.truth.t_s):
        while k < len(fixes) and fixes[k][0] <= t:
            est.update_gnss(fixes[k][1])
            k += 1
        e = est.update(make_sample(t, run.gyro[i], run.accel[i], run.mag[i]))
        if e.flags & EstimateFlags.INITIALISING or i % 97 or e.nav is None:
            continue
        x, P = est._x, est._P
        # attitude: the filter's body → true NED turned to magnetic north, scalar ≥ 0
        q_true = x["q"]
        r_mag = Rotation.from_euler("z", -DECLINATION) * rot(q_true)
        q_mag = np.roll(r_mag.as_quat(), 1)
        q_mag *= np.sign(q_mag[0])
        offset = est._published.offset_rad   # the published heading's slew (estimator/published_heading.py)
        if offset == 0.0:
            np.testing.assert_allclose(e.q_wxyz, q_mag, atol=1e-12)
        yaw_true, pitch, roll = rot(q_true).as_euler("ZYX")
        assert math.isclose(e.roll_rad, roll, abs_tol=1e-12)
        assert math.isclose(e.pitch_rad, pitch, abs_tol=1e-12)
        assert math.isclose(e.heading_true_rad, (yaw_true + offset) % (2 * math.pi), abs_tol=1e-9)
        np.testing.assert_array_equal(e.gyro_bias_rad_s, x["gyro_bias_rad_s"])
        # the rate is the sample less the bias (scale factor and misalignment: small, well inside 1e-3 rad/s)
        np.testing.assert_allclose(e.rate_body_rad_s, run.gyro[i] - x["gyro_bias_rad_s"], atol=1e-3)
        if offset == 0.0:
            # aided: with the accelerometer axes' heading term in quadrature (estimator/accel_axes_heading.py)
            sigma_yaw = math.hypot(math.sqrt(P[2, 2]), est.params.accel_axes_heading_sigma_rad)
            assert math.isclose(e.sigma_rpy_rad[2], sigma_yaw, rel_tol=1e-12)
        # roll and pitch 1σ: the NED tilt covariance along the heading (the roll axis) and across it, with the
        # accelerometer axes' tilt term in quadrature (estimator/accel_axes_tilt.py)
        along = np.array([math.cos(yaw_true), math.sin(yaw_true)])
        across = np.array([-math.sin(yaw_true), math.cos(yaw_true)])
        # at the filter's attitude and low-passed specific force (the coordinated turn's, not gravity's)
        axes_roll, axes_pitch = accel_axes_tilt_variance_in_force_rad2(tuple(quat_to_dcm(x["q"]).ravel()),
                                                                       *x["acc_ned_lp_m_s2"],
                                                                       est.params.accel_axes_tilt_sigma_rad)
        assert axes_roll > 0.0 and axes_pitch > 0.0
        # (the z axis's lean is the E_AZ_LEAN states': already in P's tilt block, nothing more is added)
        assert math.isclose(e.sigma_rpy_rad[0], math.sqrt(along @ P[:2, :2] @ along + axes_roll), rel_tol=1e-9)
        assert math.isclose(e.sigma_rpy_rad[1], math.sqrt(across @ P[:2, :2] @ across + axes_pitch), rel_tol=1e-9)
        n = e.nav
        np.testing.assert_array_equal(n.vel_ned_m_s, x["vel_ned_m_s"])
        assert n.lat_deg == math.degrees(x["lat_rad"])
        assert math.isclose(n.lon_deg, math.degrees(x["lon_rad"]), abs_tol=1e-12)
        assert n.alt_m == x["h_m"]
        np.testing.assert_array_equal(n.sigma_vel_m_s, np.sqrt(np.diag(P)[core.E_V:core.E_V + 3]))
        np.testing.assert_array_equal(n.sigma_pos_m, np.sqrt(np.diag(P)[core.E_P:core.E_P + 3]))
        np.testing.assert_array_equal(n.accel_bias_m_s2, x["accel_bias_m_s2"])
        checked += 1
    assert checked > 50
