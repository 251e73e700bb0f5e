"""`mekf`'s published 1σ against its error, at rest and in a steady turn without GNSS: at most 1 % of the samples
may lie beyond 3σ per axis (roll, pitch, heading), and σ must not be a blanket (its median within a few times
the RMS error). Truth is built here with scipy (attitude, specific force = C_nᵇ (a − g), field), never with
the estimator's own rotation maths; the sensor noise is the white noise mekf's parameters assume."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.core.estimate import EstimateFlags
from ahrsd.core.sample import make_sample
from ahrsd.estimator.mekf import DEFAULT_MEKF_PARAMS, Mekf

G = 9.81
FIELD_NED = np.array([27.86, 0.0, 41.04])  # µT, magnetic north, dip 55.8°
RATE_HZ = 200.0
SETTLE_S = 15.0
ARW = DEFAULT_MEKF_PARAMS.gyro_noise_rad_s_sqrt_hz   # rad/√s: the gyro white noise mekf assumes
ACC_NOISE = 0.05                                     # m/s² per sample


def _run(t, heading_rad, speed_m_s, seed):
    """A level vehicle (no bank) on a course heading(t) at constant speed: centripetal a = ω × v in NED.
    Returns the per-sample (roll, pitch, heading) errors and published 1σ after SETTLE_S, rad."""
    rng = np.random.default_rng(seed)
    n = len(t)
    r = Rotation.from_euler("ZYX", np.stack([heading_rad, np.zeros(n), np.zeros(n)], axis=-1))
    rate_d = np.gradient(heading_rad, t)
    # velocity along the heading; centripetal acceleration ω_D × v (ω_D down, v horizontal)
    v_ned = speed_m_s * np.stack([np.cos(heading_rad), np.sin(heading_rad), np.zeros(n)], axis=1)
    a_ned = np.cross(np.stack([np.zeros(n), np.zeros(n), rate_d], axis=1), v_ned)
    f_body = r.inv().apply(a_ned - np.array([0.0, 0.0, G]))
    gyro = np.stack([np.zeros(n), np.zeros(n), rate_d], axis=1)   # level: body z is down
    gyro = gyro + math.radians(0.05) + ARW * math.sqrt(RATE_HZ) * rng.standard_normal((n, 3))
    acc = f_body + ACC_NOISE * rng.standard_normal((n, 3))
    mag = r.inv().apply(FIELD_NED) + 0.2 * rng.standard_normal((n, 3))
    f = Mekf(accel_bias_sigma_m_s2=0.0)   # the accelerometer above has no bias (exactly calibrated)
    err = np.full((n, 3), np.nan)
    sig = np.full((n, 3), np.nan)
    for i in range(n):
        out = f.update(make_sample(t[i], gyro[i], acc[i], mag[i]))
        if t[i] >= SETTLE_S and not out.flags & EstimateFlags.INITIALISING:
            q = np.asarray(out.q_wxyz)
            e = (Rotation.from_quat([q[1], q[2], q[3], q[0]]) * r[i].inv()).as_rotvec()   # NED error rotation
            c, s = math.cos(heading_rad[i]), math.sin(heading_rad[i])
            err[i] = (c * e[0] + s * e[1], -s * e[0] + c * e[1], e[2])
            sig[i] = out.sigma_rpy_rad
    ok = np.all(np.isfinite(err), axis=1)
    return err[ok], sig[ok]


def _check_honest(err, sig, axes):
    beyond = np.mean(np.abs(err) > 3.0 * sig, axis=0)
    rms = np.sqrt(np.mean(err**2, axis=0))
    med = np.median(sig, axis=0)
    for i in axes:
        assert beyond[i] <= 0.01, f"axis {i}: {100 * beyond[i]:.1f} % beyond 3σ (σ median {np.degrees(med[i]):.3f}°, " \
                                  f"RMS error {np.degrees(rms[i]):.3f}°)"
        assert med[i] <= 4.0 * rms[i], f"axis {i}: σ median {np.degrees(med[i]):.3f}° is a blanket against " \
                                       f"RMS error {np.degrees(rms[i]):.3f}°"


def test_sigma_is_honest_at_rest():
    """At rest the low-passed vertical is on average acc_lowpass_tau_s old: the random walk the gyro noise
    made since is in the error but not in the covariance. (Broken by dropping that term from the published
    σ: 8–16 % beyond 3σ.)"""
    t = np.arange(int(45.0 * RATE_HZ)) / RATE_HZ
    err, sig = _run(t, np.full(len(t), math.radians(30.0)), 0.0, seed=1)
    _check_honest(err, sig, axes=(0, 1))


@pytest.mark.parametrize("seed", [2])
def test_sigma_is_honest_in_a_steady_turn(seed):
    """A boat at 2 m/s turning 9 °/s for 30 s: the centripetal 0.31 m/s² leans the apparent vertical by 1.8°,
    which |f| cannot show; roll follows it and heading follows roll through the dip. The published σ carries
    that lean (turn_speed_m_s). (Broken by turn_speed_m_s = 0: nearly all samples beyond 3σ.)"""
    t = np.arange(int(60.0 * RATE_HZ)) / RATE_HZ
    w = math.radians(9.0)
    # straight for 20 s, then the turn rate ramps in over 2 s and holds
    ramp = np.clip((t - 20.0) / 2.0, 0.0, 1.0)
    rate = w * 0.5 * (1.0 - np.cos(math.pi * ramp))
    heading = math.radians(30.0) + np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t))])
    err, sig = _run(t, heading, 2.0, seed)
    assert np.degrees(np.sqrt(np.mean(err[:, 0] ** 2))) > 0.5   # the turn does lean the horizon
    _check_honest(err, sig, axes=(0, 1, 2))
