"""The levelling filter of a `calibrate mag --gnss` magnetometer pass (calibration.backstepping_aided) is told the
heading 1σ the previous fit states for its calibration, as the daemon is told a saved calibration's."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.calibration.mag.backstepping_aided import (aided_roll_pitch, heading_only_overrides,
                                                      stated_heading_sigma_rad)
from ahrsd.calibration.mag.fit_types import MagFitInput, MagFitResult
from ahrsd.simulation import DEFAULT_SITE, open_stream, simulate_gnss


def test_a_magnetometer_pass_levels_with_the_previous_fits_stated_heading_sigma(caplog):
    """The filter of a magnetometer pass is told the calibration's stated heading 1σ (heading_only_overrides):
    without it `ins` takes the magnetometer for an uncalibrated one (20°, rejected when the GNSS-held heading
    disagrees), and its yaw comes from the GNSS velocity alone, 7° RMS off here with the magnetometer exactly
    calibrated; the levelling then projects the GNSS acceleration through that yaw (docs/magcal-vehicle.md).
    Truth from the simulator, via scipy; the stated σ the fit's √(varying² + offset²), as the daemon reads it.

    The magnetometer heading is 10° off for 1 s at the start, as the filter's own unconverged tilt makes it (at a
    high dip the heading at a tilt 3° off; docs/magcal-vehicle.md "A magnetometer rejected at the start"): the
    pass's filter keeps fusing it with its stated σ (the heading checks off). With the checks on they reject it
    and the yaw is the GNSS velocity's for the rest of the run (3–4° RMS off here); told no σ, 0.9°."""
    caplog.set_level(logging.ERROR)
    stated = MagFitResult(model=None, residual_rms_ut=0.1, method="backstepping",
                          quality={"predicted_heading": {"heading_dependent_std_deg": 0.18, "offset_std_deg": 0.24}})
    assert math.degrees(stated_heading_sigma_rad(stated)) == pytest.approx(0.30)
    rate_hz = 20.0      # the filter's cost is per sample: 40 s at 20 SPS
    stream = open_stream("boat", rate_hz=rate_hz, seed=11, site=DEFAULT_SITE)
    b = stream.next_block(int(40 * rate_hz))
    fixes = simulate_gnss(b, rate_hz=5.0, seed=1011)
    e = stream.errors
    exact = (b.mag_ut - e.hard_iron_ut) @ np.linalg.inv(e.soft_iron).T      # raw = S·B + h, inverted
    start = (b.t_s >= 5.0) & (b.t_s < 6.0)
    exact[start] = Rotation.from_euler("z", 10.0, degrees=True).apply(exact[start])
    data = MagFitInput(b.t_s, np.ascontiguousarray(exact), b.accel_m_s2, b.gyro_rad_s)
    yaw = []
    overrides = heading_only_overrides(None, stated_heading_sigma_rad(stated))
    assert not overrides["mag_moves_tilt"] and not overrides["mag_trusted_moves_tilt"]   # heading only
    aided_roll_pitch(data, fixes, stream.earth_field.declination_rad, mag_enabled=True, smooth=False,
                     filter_overrides=overrides, watch=lambda est: (lambda out: yaw.append(out.yaw_rad)))
    q = b.truth_q_wxyz
    true_yaw = Rotation.from_quat(np.column_stack([q[:, 1:], q[:, :1]])).as_euler("ZYX")[:, 0]
    err = np.degrees(np.angle(np.exp(1j * (np.array(yaw) + stream.earth_field.declination_rad - true_yaw))))
    rms = float(np.sqrt(np.mean(err[b.t_s > 30.0] ** 2)))
    assert rms < 0.5, rms
