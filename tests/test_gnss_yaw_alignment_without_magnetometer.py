"""ins with the magnetometer off (`mag_enabled=False`: what `calibrate mag --gnss`'s magnetometer-free levelling
runs, and what a user without a magnetometer gets) sets its yaw to the GNSS yaw bank's once a valid bank yaw
disagrees with it beyond their joint 3σ (HeadingConfirmation.alignment_due), and keeps its own where they agree.
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


def _run(kind: str, seed: int, rate_hz: float, seconds: float, site=DEFAULT_SITE, every: int = 4) -> dict:
    """The simulated vehicle fed sample by sample to ins without a magnetometer; per sample the filter's own yaw
    error (deg, against the truth) and the velocities rejected so far; at every `every`-th sample ("read") the
    published yaw error and 1σ (deg) and the published roll and pitch errors and 1σ (deg) (NaN at the others: they
    are stepped without building an estimate, which changes none, estimator/estimate_view.py); at the end the
    horizontal accelerometer bias error (m/s², against the simulator's turn-on bias)."""
    stream = open_stream(kind, rate_hz=rate_hz, seed=seed, **({"site": site} if site is not None else {}))
    b = stream.next_block(int(round(seconds * rate_hz)))
    fixes = simulate_gnss(b, rate_hz=5.0, seed=1000 + seed)
    est = Ins(declination_rad=stream.earth_field.declination_rad, mag_enabled=False)
    q = b.truth_q_wxyz
    true_yaw, true_pitch, true_roll = Rotation.from_quat(np.column_stack([q[:, 1:], q[:, :1]])).as_euler("ZYX").T
    n = len(b.t_s)
    own, pub, sigma, rejected = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan), np.zeros(n, int)
    tilt, tilt_sigma = np.full((n, 2), np.nan), np.full((n, 2), np.nan)
    read = np.zeros(n, dtype=bool)
    known = False                      # a yaw published (the filter's own is read from then on, at every sample)
    feed = GnssFixFeed(est, fixes)     # each fix before the first sample not earlier than it
    for i, t in enumerate(b.t_s):
        feed.offer_until(t)
        view = est.step(make_sample(t, b.gyro_rad_s[i], b.accel_m_s2[i], b.mag_ut[i]))
        rejected[i] = est.gnss_counters.rejected_velocity
        if i % every == 0:
            e = view.snapshot()
            known = known or e.yaw_rad is not None
            if e.yaw_rad is not None:
                read[i] = True
                pub[i], sigma[i] = e.heading_true_rad - true_yaw[i], e.sigma_rpy_rad[2]
                tilt[i] = e.roll_rad - true_roll[i], e.pitch_rad - true_pitch[i]
                tilt_sigma[i] = e.sigma_rpy_rad[:2]
        if known:
            x = est._x["q"]
            own[i] = math.atan2(2.0 * (x[0] * x[3] + x[1] * x[2]), 1.0 - 2.0 * (x[2] ** 2 + x[3] ** 2)) - true_yaw[i]
    wrap = lambda a: np.degrees((a + np.pi) % (2.0 * np.pi) - np.pi)     # noqa: E731
    return {"t": b.t_s, "read": read, "own": wrap(own), "pub": wrap(pub), "sigma": np.degrees(sigma),
            "rejected": rejected,
            "alignments": est.gnss_yaw_alignments, "tilt": wrap(tilt), "tilt_sigma": np.degrees(tilt_sigma),
            "bias_err": est._x["accel_bias_m_s2"][:2] - stream.errors.accel_bias_m_s2[:2]}


@pytest.mark.parametrize("rate_hz", [819.2, 400.0])
def test_a_car_without_a_magnetometer_takes_the_valid_gnss_yaw(caplog, rate_hz):
    """The car starts ~90° off and accelerates away. At the chip's rate the velocities that would pull its yaw in
    are rejected: without the alignment 21 in the first 10 s, then 119 of the 125 from 15 to 40 s, the yaw still
    74° off at 13 s and up to 54° off after 15 s, while the bank's is valid and 3° off. At 400 SPS they pull it in
    slowly through the linearised update, 23° off with a 6.6° σ when the bank is first valid (1.4° off, σ 5.8°),
    and up to 13° off after 15 s, its tilt and biases taught by the wrong yaw. Set to the first valid bank's yaw
    (10.5 s) it is within 4.0° from 15 s and every later velocity is fused; the published yaw is slewed to it, its
    1σ covering the error. Broken (the alignment dropped; or gated by the filter's own σ as well as the bank's,
    which the pull-in has shrunk faster than its error) it stays off."""
    caplog.set_level(logging.ERROR)
    o = _run("car", 0, rate_hz, 40.0)
    after = o["t"] >= 15.0
    # measured 4.0° / 3.9°: the tilt relevelled at the alignment (YawReset.relevel), the yaw wanders within
    # its own σ (the bank's, 5–6°) until the car's turn at 24 s brings it within 0.4°
    assert np.max(np.abs(o["own"][after])) < 4.5, np.max(np.abs(o["own"][after]))
    assert o["alignments"] == 1
    assert o["rejected"][-1] - o["rejected"][np.argmax(after)] == 0, o["rejected"][-1]
    assert o["rejected"][-1] < 30, o["rejected"][-1]                                      # measured 21 / 20
    late = (o["t"] >= 5.0) & o["read"]
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
    after &= o["read"]
    assert np.mean(np.abs(o["pub"][after]) > 3.0 * o["sigma"][after]) <= 0.01
    assert o["alignments"] == 0


def test_a_car_whose_yaw_agrees_with_the_first_valid_gnss_yaw_relearns_its_level():
    """Car seed 3 at 400 SPS: standing, then accelerating away at 3.6 m/s² with its yaw 80° off, the linearised
    pull-in puts the mis-projected GNSS acceleration into the x accelerometer bias (−300 mm/s², the truth −87) and
    the tilt; at the first valid bank yaw (10 s) the filter is inside the bank's 3σ and keeps its yaw, but the
    horizontal bias goes back to its start-up value and the tilt gets its start-up σ (YawReset.restart_horizontal_
    accel_bias, YawReset.relevel), and the car's turns re-learn them with a known yaw. Broken (kept as
    learned) the pitch is 1.1° RMS off from 30 s with all of it beyond 3σ and the bias 160 mm/s² off at 60 s
    (measured); restarted, 0.37°, none beyond 3σ, 17 mm/s²."""
    o = _run("car", 3, 400.0, 60.0)
    assert o["alignments"] == 0
    late = (o["t"] >= 30.0) & o["read"]
    err, sd = o["tilt"][late], o["tilt_sigma"][late]
    assert float(np.sqrt(np.mean(np.sum(np.square(err), axis=1)))) < 0.6
    assert np.mean(np.abs(err) > 3.0 * sd) <= 0.01
    assert np.max(np.abs(o["bias_err"])) < 0.08, o["bias_err"]
