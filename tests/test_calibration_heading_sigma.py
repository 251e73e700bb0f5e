"""Without GNSS the magnetometer calibration is the only heading reference, and `mekf`'s published yaw 1σ must carry
the heading error the calibration leaves (estimator/calibration_heading.py): σ_pub² = σ_filter² + σ_cal².

(`ins` before its first fix: the same.) A level vehicle turns in place with a hard iron in the field that the calibration in force did not remove. Truth
(attitude, field) is built here with scipy, the heading error the iron causes is compared with the published σ:
* no calibration (σ_cal NaN): the heading is unknown: UNKNOWN state, σ covering every error;
* a calibration stating the field error it leaves (the fit residual ε perpendicular to H: σ_cal = ε/H): errors of
  tens of degrees within 3σ while the heading state stays MAGNETOMETER;
* a good calibration (no iron left, σ_cal 0.5°): σ stays what the filter says in the turn (5–6°) and honest."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.core.estimate import EstimateFlags, HeadingState
from ahrsd.core.sample import make_sample
from ahrsd.estimator.ins import Ins
from ahrsd.estimator.mekf import DEFAULT_MEKF_PARAMS, Mekf

G = 9.81
FIELD_NED = np.array([20.0, 0.0, 45.0])      # µT, magnetic north: H = 20 µT, dip 66°
H_UT = float(np.hypot(FIELD_NED[0], FIELD_NED[1]))
RATE_HZ = 100.0
DURATION_S = 90.0
SETTLE_S = 10.0
TURN_RATE_RAD_S = math.radians(12.0)
ARW = DEFAULT_MEKF_PARAMS.gyro_noise_rad_s_sqrt_hz


def _run(hard_iron_ut, mag_calibration_sigma_rad, seed=3, estimator=Mekf):
    """Heading errors (rad, wrapped), published yaw 1σ (rad) and heading states after SETTLE_S."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, DURATION_S, 1.0 / RATE_HZ)
    n = len(t)
    heading = (0.3 + TURN_RATE_RAD_S * t) % (2 * math.pi)
    r = Rotation.from_euler("ZYX", np.stack([heading, np.zeros(n), np.zeros(n)], axis=-1))
    gyro = np.tile([0.0, 0.0, TURN_RATE_RAD_S], (n, 1)) + ARW * math.sqrt(RATE_HZ) * rng.standard_normal((n, 3))
    acc = np.tile([0.0, 0.0, -G], (n, 1)) + 0.05 * rng.standard_normal((n, 3))
    mag = r.inv().apply(FIELD_NED) + np.asarray(hard_iron_ut, dtype=float) + 0.2 * rng.standard_normal((n, 3))
    f = estimator(mag_calibration_sigma_rad=mag_calibration_sigma_rad)
    err, sig, states = [], [], []
    for i in range(n):
        out = f.update(make_sample(t[i], gyro[i], acc[i], mag[i]))
        if t[i] < SETTLE_S or out.flags & EstimateFlags.INITIALISING and out.heading_state != HeadingState.UNKNOWN:
            continue
        q = np.asarray(out.q_wxyz)
        yaw = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_euler("ZYX")[0]
        err.append((yaw - heading[i] + math.pi) % (2 * math.pi) - math.pi)
        sig.append(out.sigma_rpy_rad[2])
        states.append(out.heading_state)
    return np.array(err), np.array(sig), states


@pytest.mark.parametrize("estimator", [Mekf, Ins])
def test_no_calibration_the_heading_is_unknown_and_sigma_covers_the_iron(estimator):
    # 12.6 µT of horizontal hard iron against H = 20 µT turns the magnetometer heading by up to asin(12.6/20) = 39°
    # (ins, no fix yet, weighs an uncalibrated magnetometer little and follows it less)
    err, sig, states = _run((12.0, -4.0, 3.0), math.nan, estimator=estimator)
    assert np.max(np.abs(err)) > math.radians(5.0)           # the iron is really there
    assert np.all(np.abs(err) <= 3.0 * sig)
    assert set(states) == {HeadingState.UNKNOWN}


def test_a_calibration_stating_the_error_it_leaves_covers_it():
    # the fit left 4.6 µT of horizontal field error perpendicular to H on average: σ_cal = ε/H = 13° (heading_trust
    # route 2); the iron turns the heading by up to asin(6.5/20) = 19°, beyond 3σ of the filter's own 5–6° in this turn
    b = np.array([4.6, -4.6, 2.0])
    eps_ut = float(np.hypot(b[0], b[1])) / math.sqrt(2.0)   # RMS over headings of the component ⟂ H
    err, sig, states = _run(b, math.atan2(eps_ut, H_UT))
    beyond = float(np.mean(np.abs(err) > 3.0 * sig))
    print(f"\nmissing iron {np.hypot(b[0], b[1]):.1f} µT: max |err| {math.degrees(np.max(np.abs(err))):.1f}°, "
          f"σ median {math.degrees(np.median(sig)):.1f}°, beyond 3σ {100 * beyond:.1f} %")
    assert np.max(np.abs(err)) > math.radians(17.0)
    assert beyond <= 0.01
    assert states.count(HeadingState.MAGNETOMETER) == len(states)


def test_a_good_calibration_keeps_sigma_small():
    err, sig, states = _run((0.0, 0.0, 0.0), math.radians(0.5))
    beyond = float(np.mean(np.abs(err) > 3.0 * sig))
    assert beyond <= 0.01
    assert math.radians(0.5) <= np.median(sig) < math.radians(10.0)    # well inside the 15° "unknown" limit
    assert states.count(HeadingState.MAGNETOMETER) == len(states)


def test_ins_before_its_first_fix_carries_the_stated_calibration_error():
    """ins fuses the magnetometer with its calibration's σ as a correlated error, but its yaw σ still shrinks
    below it: until a fix aids it the published σ adds the calibration's error as mekf's does."""
    b = np.array([4.6, -4.6, 2.0])
    sigma_cal = math.atan2(4.6, H_UT)
    err, sig, states = _run(b, sigma_cal, estimator=Ins)
    assert float(np.mean(np.abs(err) > 3.0 * sig)) <= 0.01
    assert np.median(sig) >= sigma_cal
