"""Roll and pitch for levelling magnetometer samples: from an attitude estimator run over the recording, aided
by GNSS fixes when there are some (the aided estimator's horizon does not lean into turns and accelerations)."""

from __future__ import annotations

import numpy as np

from ahrsd.core.sample import make_sample
from ahrsd.estimator import make_estimator
from ahrsd.estimator.base import GnssAidedEstimator
from ahrsd.estimator.fix_feed import GnssFixFeed

from .backstepping_paper import BacksteppingError
from .fit_types import MagFitInput


def roll_pitch_from_estimator(data: MagFitInput, name: str = "mekf", fixes=None,
                              **params) -> tuple[np.ndarray, np.ndarray]:
    """Run `ahrsd.estimator.make_estimator(name, **params)` over the samples (raw magnetometer: the estimator's
    design keeps magnetometer errors out of roll/pitch) and return its roll and pitch per sample.

    fixes: GNSS fixes (core.gnss.GnssFix, time order, on the samples' time base) for an aided estimator
    (estimator.base.GnssAidedEstimator, e.g. "ins"): each is offered before the first sample not earlier than
    it (estimator/fix_feed.py), as `ahrsd replay --gnss` does."""
    roll, pitch, _ = attitude_from_estimator(data, name, fixes, **params)
    return roll, pitch


def attitude_from_estimator(data: MagFitInput, name: str = "mekf", fixes=None, estimator=None, on_estimate=None,
                            **params) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """As `roll_pitch_from_estimator`, plus the estimator's own 1σ of the tilt per sample (rad,
    √(σ_roll² + σ_pitch²)): how far it has converged. `estimator`: run this (fresh) estimator object instead of
    making one (the caller then reads its counters); `on_estimate(estimate)`: called with each sample's estimate
    (the caller watches the estimator as it runs)."""
    if data.gyro_rad_s is None or data.accel_m_s2 is None:
        raise BacksteppingError("the estimator needs gyro and accelerometer samples")
    est = estimator if estimator is not None else make_estimator(name, **params)
    if fixes is not None and not isinstance(est, GnssAidedEstimator):
        raise BacksteppingError(f"estimator {name!r} takes no GNSS fixes: use an aided one (ins)")
    feed = GnssFixFeed(est, fixes) if fixes is not None else None
    n = len(data)
    roll, pitch, tilt_sigma = np.empty(n), np.empty(n), np.empty(n)
    for i in range(n):
        t = data.t_s[i]
        if feed is not None:
            feed.offer_until(t)
        e = est.update(make_sample(t, data.gyro_rad_s[i], data.accel_m_s2[i], data.mag_ut[i]))
        if on_estimate is not None:
            on_estimate(e)
        roll[i], pitch[i] = e.roll_rad, e.pitch_rad
        tilt_sigma[i] = float(np.hypot(e.sigma_rpy_rad[0], e.sigma_rpy_rad[1]))
    return roll, pitch, tilt_sigma
