"""A back-stepping fit levelled by the GNSS-aided estimator (`ahrsd calibrate mag --gnss`,
calibration/mag/backstepping_aided.py) predicts its heading error with the levelling's own error in it
(calibration/mag/levelling_error.py, issue 28): the tilt the aided filter cannot tell from an accelerometer bias
stays fixed in the body, and the fit folds it into the soft iron, where its residuals cannot show it. Before,
the prediction held the fit's data only: 0.15° offset / 0.03° varying on the tour's boat, whose calibration is
0.25° RMS off against the simulator's iron (docs/magcal-vehicle.md)."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest

from ahrsd.calibration.mag.backstepping_aided import fit_backstepping_aided
from ahrsd.calibration.mag.fit_types import MagFitInput
from ahrsd.calibration.mag.levelling_error import body_fixed_tilt_sigma_rad, tilt_heading_std_deg
from ahrsd.simulation import open_stream, simulate_gnss
from support.sim_heading import heading_error_on_other_attitudes_deg

pytestmark = pytest.mark.slow     # a long file: started first under pytest-xdist (tests/conftest.py)

RATE_HZ = 50.0      # half the tour's 100 SPS: the levelling's cost is per sample; the break of the prediction's
                    # levelling term (mag-pred-levelling-tilt) still fails here (0.168° predicted, 0.195° true RMS)
SECONDS = 200.0


def test_the_gnss_levelled_boat_fit_predicts_at_least_its_true_heading_error(caplog):
    caplog.set_level(logging.ERROR)
    stream = open_stream("boat", rate_hz=RATE_HZ, seed=0)     # `ahrsd record --sim boat`'s seed
    b = stream.next_block(int(SECONDS * RATE_HZ))
    fixes = simulate_gnss(b, rate_hz=5.0, seed=1000)
    field = stream.earth_field
    res = fit_backstepping_aided(MagFitInput(b.t_s, b.mag_ut, b.accel_m_s2, b.gyro_rad_s), fixes, field,
                                 field.declination_rad)
    assert res.ok, res.refused
    err = heading_error_on_other_attitudes_deg(res.model, stream)       # truth: the simulator's iron, scipy
    pred = res.quality["predicted_heading"]
    rms = float(np.sqrt(np.mean(err**2)))
    assert math.hypot(pred["offset_std_deg"], pred["heading_dependent_std_deg"]) >= rms, (pred, rms)
    # the heading-dependent part is the levelling's body-fixed tilt: a 1σ figure, at least the true spread here;
    # the offset's 1σ (the fit's data) can be exceeded on one draw: over the tour's seeds 0 and 11–17 its
    # true RMS is 0.13° (docs/magcal-vehicle.md), so it is not asserted here
    assert pred["heading_dependent_std_deg"] >= err.std(), (pred, err.std())
    last = res.quality["aided_levelling"]["passes"][-1]
    assert pred["levelling"]["given_tilt_sigma_deg"] == pytest.approx(last["tilt_sigma_per_axis_deg"])


def test_the_levelling_tilt_turns_the_heading_by_tan_dip():
    # dip 60°: tan 60° = √3; 1 mrad of body-fixed tilt per axis → √3 mrad of heading, RMS over heading
    total = 50.0
    vertical = total * math.sin(math.radians(60.0))
    assert tilt_heading_std_deg(1e-3, vertical, total) == pytest.approx(math.degrees(math.sqrt(3.0) * 1e-3),
                                                                        rel=1e-9)


def test_the_body_fixed_tilt_sigma_is_the_rms_per_axis_of_the_filters_tilt_sigma():
    # √(σ_roll² + σ_pitch²) per sample, NaN before the filter started: RMS over the started samples, ÷ √2
    tilt = np.array([math.nan, 0.3, 0.4, 0.0])
    assert body_fixed_tilt_sigma_rad(tilt) == pytest.approx(math.sqrt((0.09 + 0.16 + 0.0) / 3.0 / 2.0), rel=1e-12)
    assert math.isnan(body_fixed_tilt_sigma_rad(np.array([math.nan])))
