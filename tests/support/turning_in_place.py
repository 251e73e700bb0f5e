"""The field-circle tests' vehicle: a level vehicle turning in place without GNSS, whose magnetometer calibration
leaves a given hard iron in the field while it claims 0.5° (tests/test_field_circle*.py, test_learned_iron_turns).
The truth (its heading, the field the body sees) is built here with scipy and numpy, never taken from the code
under test; also the circle check fed constructed level fields, and the daemon's heading status fed the estimates.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from ahrsd.core.sample import make_sample
from ahrsd.estimator.mekf import DEFAULT_MEKF_PARAMS, Mekf

G = 9.81
FIELD_NED = np.array([20.0, 0.0, 45.0])      # µT, magnetic north: H = 20 µT, dip 66°
H_UT = float(np.hypot(FIELD_NED[0], FIELD_NED[1]))
RATE_HZ = 100.0
TURN_RATE_RAD_S = math.radians(12.0)      # the check's constructed fields
VEHICLE_TURN_RATE_RAD_S = math.radians(4.0)   # the filters' vehicle: a slow turn leaves little lean in σ
CLAIMED_SIGMA_RAD = math.radians(0.5)


def levelled_fields(check, headings_rad, centre_ut, radius_ut=H_UT, noise_ut=0.3, seed=1, scale_x=1.0,
                    drift_ut_per_s=0.0, rate_hz=10.0):
    """Feed the check level fields (roll = pitch = 0) of a body at `headings_rad`: the Earth's horizontal field seen
    from the body, R_z(−ψ)·(H, 0), times a soft-iron x scale, plus a constant offset, noise and a drift of the
    magnitude along the way."""
    rng = np.random.default_rng(seed)
    for k, psi in enumerate(headings_rad):
        t = k / rate_hz
        r = radius_ut + drift_ut_per_s * t
        m = np.array([r * math.cos(-psi) * scale_x, r * math.sin(-psi), 40.0])
        m[:2] += np.asarray(centre_ut, dtype=float) + noise_ut * rng.standard_normal(2)
        check.add(t, 0.0, 0.0, m, math.radians(0.1))
    return check.result


def turning_headings(seconds, rate_hz=10.0):
    """Headings (rad) of a body turning at TURN_RATE_RAD_S for `seconds`, sampled at `rate_hz`."""
    t = np.arange(0.0, seconds, 1.0 / rate_hz)
    return 0.3 + TURN_RATE_RAD_S * t


def run_turning(estimator, centre_error_ut, seconds=240.0, seed=3, yaw_rate_rad_s=None, estimates_every=1):
    """A level vehicle turning in place at 4 °/s (or at `yaw_rate_rad_s(t)`, rad/s per sample); its calibration
    leaves `centre_error_ut` (body x, y, or x, y, z; or one such row per sample: an iron that moves) in the field
    while claiming 0.5°. Returns time, heading error (rad, wrapped; truth from scipy), published yaw σ, the
    estimates and the filter. The estimates: (AttitudeEstimate, circle check) per sample; with `estimates_every`
    k > 1 the AttitudeEstimate is built only for every k-th sample and the last (None between: heading_status_over
    reads every 10th), the attitude and σ read from the estimator's view at every sample (the same values)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 1.0 / RATE_HZ)
    n = len(t)
    rate = np.full(n, VEHICLE_TURN_RATE_RAD_S) if yaw_rate_rad_s is None else yaw_rate_rad_s(t)
    heading = (0.3 + np.concatenate([[0.0], np.cumsum(rate[:-1]) / RATE_HZ])) % (2 * math.pi)
    r = Rotation.from_euler("ZYX", np.stack([heading, np.zeros(n), np.zeros(n)], axis=-1))
    arw = DEFAULT_MEKF_PARAMS.gyro_noise_rad_s_sqrt_hz
    gyro = np.stack([np.zeros(n), np.zeros(n), rate], axis=1) + arw * math.sqrt(RATE_HZ) * rng.standard_normal((n, 3))
    acc = np.tile([0.0, 0.0, -G], (n, 1)) + 0.05 * rng.standard_normal((n, 3))
    error = np.zeros((n, 3))
    given = np.atleast_2d(np.asarray(centre_error_ut, dtype=float))
    error[:, :given.shape[1]] = given
    mag = r.inv().apply(FIELD_NED) + error + 0.2 * rng.standard_normal((n, 3))
    f = estimator(mag_calibration_sigma_rad=CLAIMED_SIGMA_RAD)
    q, sig, ests = np.full((n, 4), np.nan), np.full(n, np.nan), []
    circle = f.field_circle if isinstance(f, Mekf) else f.field_circle_check
    step = f.update if estimates_every == 1 else f.step      # the view: the snapshot only where it is kept
    for i in range(n):
        out = step(make_sample(t[i], gyro[i], acc[i], mag[i]))
        q[i] = out.q_wxyz
        sig[i] = out.sigma_rpy_rad[2]
        kept = out if estimates_every == 1 else (
            out.snapshot() if i % estimates_every == 0 or i == n - 1 else None)
        ests.append((kept, circle()))
    yaw = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_euler("ZYX")[:, 0]   # scipy, once for the whole run
    err = (yaw - heading + math.pi) % (2 * math.pi) - math.pi
    return t, err, sig, ests, f


def heading_status_over(ests, step=10):
    """The daemon's heading status fed the estimates (at 10 Hz) with the estimator's circle check."""
    from ahrsd.daemon.heading_status import HeadingStatus

    texts = []
    hs = HeadingStatus(lambda sev, text: texts.append(text), good_sigma_rad=math.radians(5.0),
                       calibration_sigma_rad=CLAIMED_SIGMA_RAD, calibration_in_force=True)
    good = []
    for k in range(0, len(ests), step):
        est, fc = ests[k]
        hs.on_estimate(est, k / RATE_HZ, field_circle=fc)
        good.append(hs.heading_good)
    return hs, texts, np.array(good)
