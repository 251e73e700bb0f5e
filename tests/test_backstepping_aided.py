"""Back-stepping levelled by the GNSS-aided estimator (calibration.backstepping_aided) on the simulated boat:
a seed on which the aided filter without a magnetometer never acquires its heading from the GNSS velocity.
Levelled by it alone (the behaviour before), the fit was 5° off; the fallback levels again with the
magnetometer calibrated by the accelerometer-levelled fit."""

from __future__ import annotations

import logging

import numpy as np
from scipy.spatial.transform import Rotation

from ahrsd.calibration.backstepping_aided import fit_backstepping_aided
from ahrsd.calibration.magfit import MagFitInput
from ahrsd.simulation import DEFAULT_SITE, open_stream, simulate_gnss


def heading_error_on_other_attitudes_deg(model, stream) -> np.ndarray:
    """The calibration on the noise-free raw field of the same sensor at every 10° of heading, roll and pitch
    in ±8°, tilt-compensated with the true tilt, against the true heading (scipy only)."""
    f = stream.earth_field
    y, p, r = (a.ravel() for a in np.meshgrid(np.radians(np.arange(0, 360, 10.0)), np.radians([-8.0, 0.0, 8.0]),
                                              np.radians([-8.0, 0.0, 8.0]), indexing="ij"))
    raw = Rotation.from_euler("ZYX", np.column_stack([y, p, r])).inv().apply(f.ned_ut) @ stream.errors.soft_iron.T \
        + stream.errors.hard_iron_ut
    level = Rotation.from_euler("ZYX", np.column_stack([0 * y, p, r])).apply(model.apply(raw))
    psi = np.arctan2(-level[:, 1], level[:, 0]) + f.declination_rad
    return np.degrees(np.angle(np.exp(1j * (psi - y))))


def test_a_filter_that_never_acquires_its_heading_is_not_trusted(caplog):
    caplog.set_level(logging.ERROR)
    stream = open_stream("boat", rate_hz=100.0, seed=8, site=DEFAULT_SITE)
    b = stream.next_block(18000)
    fixes = simulate_gnss(b, rate_hz=5.0, seed=1008)
    data = MagFitInput(b.t_s, b.mag_ut, b.accel_m_s2, b.gyro_rad_s)
    res = fit_backstepping_aided(data, fixes, stream.earth_field, stream.earth_field.declination_rad)
    assert res.ok, res.refused
    passes = res.quality["aided_levelling"]["passes"]
    assert not passes[0]["healthy"] and passes[0]["gnss"]["reset_velocity"] > 0
    err = heading_error_on_other_attitudes_deg(res.model, stream)
    assert np.sqrt(np.mean(err ** 2)) < 0.5, np.sqrt(np.mean(err ** 2))
