"""ins with the magnetometer off (`mag_enabled=False`: what `calibrate mag --gnss`'s magnetometer-free levelling
runs, and what a user without a magnetometer gets) sets its yaw to the GNSS yaw bank's once a valid bank yaw
disagrees with it beyond their joint 3σ (Ins._gnss_yaw_alignment_due), and keeps its own where they agree.
Truth: the simulator's attitude, through scipy's rotations (not the estimator's)."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.core.sample import make_sample
from ahrsd.estimator.fix_feed import GnssFixFeed
from ahrsd.estimator.ins import Ins
from ahrsd.simulation import DEFAULT_SITE, open_stream, simulate_gnss


def _run(kind: str, seed: int, rate_hz: float, seconds: float, site=DEFAULT_SITE) -> dict:
    """The simulated vehicle fed sample by sample to ins without a magnetometer; per sample the filter's own yaw
    error (deg, against the truth), the published yaw error and 1σ (deg), and the velocities rejected so far."""
    stream = open_stream(kind, rate_hz=rate_hz, seed=seed, **({"site": site} if site is not None else {}))
    b = stream.next_block(int(round(seconds * rate_hz)))
    fixes = simulate_gnss(b, rate_hz=5.0, seed=1000 + seed)
    est = Ins(declination_rad=stream.earth_field.declination_rad, mag_enabled=False)
    q = b.truth_q_wxyz
    true_yaw = Rotation.from_quat(np.column_stack([q[:, 1:], q[:, :1]])).as_euler("ZYX")[:, 0]
    n = len(b.t_s)
    own, pub, sigma, rejected = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan), np.zeros(n, int)
    feed = GnssFixFeed(est, fixes)     # each fix before the first sample not earlier than it
    for i, t in enumerate(b.t_s):
        feed.offer_until(t)
        e = est.update(make_sample(t, b.gyro_rad_s[i], b.accel_m_s2[i], b.mag_ut[i]))
        rejected[i] = est.gnss_counters.rejected_velocity
        if e.yaw_rad is None:
            continue
        x = est._x["q"]
        yaw = math.atan2(2.0 * (x[0] * x[3] + x[1] * x[2]), 1.0 - 2.0 * (x[2] ** 2 + x[3] ** 2))
        own[i], pub[i], sigma[i] = yaw - true_yaw[i], e.heading_true_rad - true_yaw[i], e.sigma_rpy_rad[2]
    wrap = lambda a: np.degrees((a + np.pi) % (2.0 * np.pi) - np.pi)     # noqa: E731
    return {"t": b.t_s, "own": wrap(own), "pub": wrap(pub), "sigma": np.degrees(sigma), "rejected": rejected,
            "alignments": est.gnss_yaw_alignments}


@pytest.mark.parametrize("rate_hz", [819.2, 400.0])
def test_a_car_without_a_magnetometer_takes_the_valid_gnss_yaw(caplog, rate_hz):
    """The car starts ~90° off and accelerates away. At the chip's rate the velocities that would pull its yaw in
    are rejected: without the alignment 21 in the first 10 s, then 119 of the 125 from 15 to 40 s, the yaw still
    74° off at 13 s and up to 54° off after 15 s, while the bank's is valid and 3° off. At 400 SPS they pull it in
    slowly through the linearised update, 23° off with a 6.6° σ when the bank is first valid (1.4° off, σ 5.8°),
    and up to 13° off after 15 s, its tilt and biases taught by the wrong yaw. Set to the first valid bank's yaw
    (10.5 s) it is within 2.7° from 15 s and every later velocity is fused; the published yaw is slewed to it, its
    1σ covering the error. Broken (the alignment dropped; or gated by the filter's own σ as well as the bank's,
    which the pull-in has shrunk faster than its error) it stays off."""
    caplog.set_level(logging.ERROR)
    o = _run("car", 0, rate_hz, 40.0)
    after = o["t"] >= 15.0
    assert np.max(np.abs(o["own"][after])) < 3.0, np.max(np.abs(o["own"][after]))      # measured 2.7°
    assert o["alignments"] == 1
    assert o["rejected"][-1] - o["rejected"][np.argmax(after)] == 0, o["rejected"][-1]
    assert o["rejected"][-1] < 30, o["rejected"][-1]                                      # measured 21 / 20
    late = o["t"] >= 5.0
    assert np.mean(np.abs(o["pub"][late]) > 3.0 * o["sigma"][late]) <= 0.01


@pytest.mark.parametrize("seed, rate_hz, seconds, site, from_s, max_err_deg", [
    (1, 100.0, 60.0, None, 20.0, 12.0),            # 8.4° (set to the bank's at its first valid yaw: 22.4°)
    (0, 200.0, 150.0, DEFAULT_SITE, 30.0, 8.0),    # 3.7° (set to it when outside its 3σ later: 13.3°)
])
def test_a_boat_whose_yaw_agrees_with_the_first_valid_gnss_yaw_keeps_it(caplog, seed, rate_hz, seconds, site,
                                                                         from_s, max_err_deg):
    """The boat's weak accelerations pull the filter's yaw in before the bank is valid (seed 1: at 17 s; the bank
    valid at 25 s, 5–6° off with a 14° σ, the filter 1° off): inside the bank's 3σ, the filter keeps its yaw and
    its biases. Broken (set to the bank's all the same) the yaw takes the bank's variance and the biases their
    start-up values, and the next velocities pull it 20° off within 4 s. Seed 0: the bank, which without the
    magnetometer's checks never gets the filter's gyro bias, drifts to 11° off while its σ shrinks to 4.4°, and
    later puts the filter's right yaw (2.4° off) outside its 3σ: only the first valid yaw decides. Broken (any
    valid yaw decides) the yaw is set 11° off."""
    caplog.set_level(logging.ERROR)
    o = _run("boat", seed, rate_hz, seconds, site=site)
    after = o["t"] >= from_s
    assert np.max(np.abs(o["own"][after])) < max_err_deg, np.max(np.abs(o["own"][after]))
    assert np.mean(np.abs(o["pub"][after]) > 3.0 * o["sigma"][after]) <= 0.01
    assert o["alignments"] == 0
