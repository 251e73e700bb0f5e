"""The simulated GNSS receiver: noise statistics, timing, lever arm, outages and glitches where configured.

The truth a fix is compared with is recomputed here from the simulator's truth arrays (scipy for the lever arm),
and the statistical bounds are a few standard errors of the sample statistics, stated at each assert.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.core.gnss import GnssFix, GnssFixType
from ahrsd.core.sample import ImuSample
from ahrsd.simulation import (GnssErrors, GnssGlitch, GnssOutage, GnssSimulator, in_arrival_order, open_stream,
                              simulate, simulate_gnss)
from ahrsd.core.gravity import EARTH_RADIUS_M


def error_ned_m(fixes):
    """Position error (measured − true antenna position) in metres north/east/down, and velocity error."""
    out_p, out_v = [], []
    for f in fixes:
        tr = f.extra["truth"]
        r = EARTH_RADIUS_M + tr.alt_m
        out_p.append([math.radians(f.lat_deg - tr.lat_deg) * r,
                      math.radians(f.lon_deg - tr.lon_deg) * r * math.cos(math.radians(tr.lat_deg)),
                      tr.alt_m - f.alt_m])
        out_v.append(f.vel_ned_m_s - tr.vel_ned_m_s)
    return np.array(out_p), np.array(out_v)


@pytest.fixture(scope="module")
def boat():
    return simulate("boat", 120.0, rate_hz=50.0, errors="ideal")


@pytest.fixture(scope="module")
def still_long():
    return simulate("static", 2000.0, rate_hz=5.0, errors="ideal")


def test_fixes_come_at_the_rate_with_the_latency_and_the_reported_accuracies(boat):
    fixes = simulate_gnss(boat, rate_hz=10.0, seed=1, latency_s=0.12)
    t = np.array([f.t_s for f in fixes])
    assert len(fixes) == 1200 and t[0] == 0.0 and t[-1] == pytest.approx(119.9)   # block ends at 119.98 s
    np.testing.assert_allclose(np.diff(t), 0.1, atol=1e-12)
    np.testing.assert_allclose([f.extra["t_rx_s"] - f.t_s for f in fixes], 0.12, atol=1e-12)
    f = fixes[5]
    assert isinstance(f, GnssFix) and f.fix_type == GnssFixType.FIX_3D and f.num_sats == 12
    assert (f.h_acc_m, f.v_acc_m, f.s_acc_m_s) == (1.5, 2.5, 0.05) and f.has_position and f.has_velocity
    assert f.extra["glitch"] is None and f.source == "simulated"
    jittered = simulate_gnss(boat, rate_hz=5.0, latency_s=0.05, jitter_s=0.03)
    lag = np.array([g.extra["t_rx_s"] - g.t_s for g in jittered])
    assert lag.min() >= 0.05 and lag.max() < 0.08 and np.ptp(lag) > 0.02
    optimistic = simulate_gnss(boat, errors=GnssErrors(h_acc_m=0.5, v_acc_m=0.8, s_acc_m_s=0.02))
    assert (optimistic[0].h_acc_m, optimistic[0].v_acc_m, optimistic[0].s_acc_m_s) == (0.5, 0.8, 0.02)


def test_total_position_error_has_the_configured_sigma_at_every_fix():
    """Across 2000 seeds, the error at one epoch has σ 1.5 m (N, E) and 2.5 m (D): the wander starts stationary,
    so the first fix is as noisy as any. Standard error of a σ estimate from 2000 draws: 1.6 %; bound 7 %."""
    b = simulate("static", 1.0, rate_hz=5.0, errors="ideal")
    first = [simulate_gnss(b, seed=s, stop_s=0.0)[0] for s in range(2000)]
    p, v = error_ned_m(first)
    np.testing.assert_allclose(p.std(axis=0), [1.5, 1.5, 2.5], rtol=0.07)
    np.testing.assert_allclose(v.std(axis=0), 0.05, rtol=0.07)
    assert np.all(np.abs(p.mean(axis=0)) < 4 * np.array([1.5, 1.5, 2.5]) / math.sqrt(2000))


def test_wander_stays_stationary():
    """With τ = 2 s, after 10 τ the wander must still carry its share (a wrong drive noise would let it decay
    or grow; sqrt(1 − φ) instead of sqrt(1 − φ²) gives 0.87): σ over 600 seeds × 3 axes at the last fix, standard
    error 1.7 %, bound 7 %."""
    b = simulate("static", 20.0, rate_hz=5.0, errors="ideal")
    model = GnssErrors(horizontal_m=1.0, vertical_m=1.0, wander_tau_s=2.0)
    last = [simulate_gnss(b, seed=s, errors=model)[-1] for s in range(600)]
    p, _ = error_ned_m(last)
    assert np.std(p) == pytest.approx(1.0, rel=0.07)


def test_white_part_velocity_and_wander_have_their_sigmas(still_long):
    """Fix-to-fix differences remove the wander (it moves by σ√(2(1−φ)) ≈ 0.04 σ per fix), leaving √2 σ_white,
    σ_white² = (1 − 0.5) σ². Over 10 000 fixes the standard error of a σ is 0.7 %; bound 4 %."""
    fixes = simulate_gnss(still_long, rate_hz=5.0, seed=7)
    p, v = error_ned_m(fixes)
    white = np.diff(p, axis=0).std(axis=0) / math.sqrt(2)
    np.testing.assert_allclose(white, np.array([1.5, 1.5, 2.5]) * math.sqrt(0.5), rtol=0.04)
    np.testing.assert_allclose(v.std(axis=0), 0.05, rtol=0.04)
    # the slow part: correlation of 60-s means 60 s apart is exp(−60/300) ≈ 0.82 for a Gauss–Markov of τ 300 s
    means = p[: len(p) // 300 * 300].reshape(-1, 300, 3).mean(axis=1)
    lag1 = np.mean([np.corrcoef(means[:-1, i], means[1:, i])[0, 1] for i in range(3)])
    assert 0.6 < lag1 < 0.95


def test_wander_share_of_the_variance_is_as_configured():
    """Per-seed means over 20 s are the wander (nearly constant over 20 s) plus white/√100: their spread across
    300 seeds is σ√0.5 (+0.5 % from the white part); standard error 4 %, bound 15 %."""
    b = simulate("static", 20.0, rate_hz=5.0, errors="ideal")
    means = np.array([error_ned_m(simulate_gnss(b, seed=s))[0].mean(axis=0) for s in range(300)])
    np.testing.assert_allclose(means.std(axis=0), np.array([1.5, 1.5, 2.5]) * math.sqrt(0.5), rtol=0.15)
    white_only = GnssErrors(wander_fraction=0.0)
    means = np.array([error_ned_m(simulate_gnss(b, seed=s, errors=white_only))[0].mean(axis=0) for s in range(300)])
    assert np.all(means.std(axis=0) < 0.2 * np.array([1.5, 1.5, 2.5]))   # white: σ/√100 = 0.1 σ


def test_same_seed_same_fixes_other_seed_other_fixes(boat):
    a, b, c = simulate_gnss(boat, seed=3), simulate_gnss(boat, seed=3), simulate_gnss(boat, seed=4)
    assert [f.lat_deg for f in a] == [f.lat_deg for f in b]
    assert a[10].lat_deg != c[10].lat_deg
    assert a[10].extra["truth"].lat_deg == c[10].extra["truth"].lat_deg


def test_stream_truth_and_block_truth_give_the_same_fixes():
    """simulate_gnss on a stream (exact truth at the epochs) and on its block (interpolated between 50-Hz
    samples) agree to the interpolation error (a Δt²/8 ≈ 1e-4 m at 0.4 g)."""
    stream = open_stream("car", rate_hz=50.0, errors="ideal")
    block = stream.next_block(50 * 60)
    from_stream = simulate_gnss(stream, seed=2)
    from_block = simulate_gnss(block, seed=2)
    assert len(from_stream) == len(from_block) == 300
    p_s, v_s = error_ned_m(from_stream)
    dp = np.array([[math.radians(a.lat_deg - b.lat_deg) * EARTH_RADIUS_M,
                    math.radians(a.lon_deg - b.lon_deg) * EARTH_RADIUS_M * 0.8, a.alt_m - b.alt_m]
                   for a, b in zip(from_stream, from_block)])
    assert np.max(np.abs(dp)) < 1e-3
    assert np.max(np.abs(np.array([a.vel_ned_m_s - b.vel_ned_m_s for a, b in zip(from_stream, from_block)]))) < 1e-3
    with pytest.raises(ValueError, match="stop_s"):
        simulate_gnss(open_stream("car"))


def test_each_epoch_has_its_own_draws_of_the_four_noise_streams(boat):
    """The noise of epoch k is the k-th draw of each of the receiver's four streams (white, wander, velocity,
    jitter: SeedSequence(seed).spawn(4)), whatever the outages: recomputed here epoch by epoch from the model the
    module docstring states, so a batched draw taken in another order (or an outage that skips draws) fails."""
    seed, rate_hz, jitter_s, latency_s = 9, 5.0, 0.04, 0.1
    model = GnssErrors()
    fixes = simulate_gnss(boat, rate_hz=rate_hz, seed=seed, jitter_s=jitter_s, latency_s=latency_s,
                          outages=[(20.0, 30.0)], errors=model)
    white_rng, wander_rng, vel_rng, jitter_rng = (np.random.default_rng(s)
                                                  for s in np.random.SeedSequence(seed).spawn(4))
    sigma = np.array([model.horizontal_m, model.horizontal_m, model.vertical_m])
    phi = math.exp(-1.0 / (rate_hz * model.wander_tau_s))
    wander = wander_rng.standard_normal(3) * sigma * math.sqrt(model.wander_fraction)
    expected = {}
    for k in range(int(119.98 * rate_hz) + 1):
        white = white_rng.standard_normal(3) * sigma * math.sqrt(1.0 - model.wander_fraction)
        wander = phi * wander + wander_rng.standard_normal(3) * sigma * math.sqrt(model.wander_fraction * (1 - phi**2))
        dv = vel_rng.standard_normal(3) * model.velocity_m_s
        t_rx = k / rate_hz + latency_s + jitter_rng.uniform(0.0, jitter_s)
        expected[round(k / rate_hz, 6)] = (white + wander, dv, t_rx)
    assert len(fixes) == len(expected) - 50          # 10 s of outage at 5 Hz
    p_err, v_err = error_ned_m(fixes)
    for f, p, v in zip(fixes, p_err, v_err):
        d_ned, dv, t_rx = expected[round(f.t_s, 6)]
        np.testing.assert_allclose(p, d_ned, atol=1e-6)      # metres; the lat/lon round trip costs ~1e-9
        np.testing.assert_allclose(v, dv, atol=1e-12)
        assert f.extra["t_rx_s"] == pytest.approx(t_rx, abs=1e-12)


def test_incremental_delivery_equals_the_batch(boat):
    batch = simulate_gnss(boat, seed=5, latency_s=0.15)
    stream = open_stream("boat", rate_hz=50.0, errors="ideal")
    sim = GnssSimulator(stream.truth_at, rate_hz=5.0, seed=5, latency_s=0.15)
    got = []
    for t_now in np.arange(0.0, 120.0 + 1e-9, 0.37):
        arrived = sim.arrivals_until(t_now)
        assert all(f.extra["t_rx_s"] <= t_now for f in arrived)
        got += arrived
    got += sim.arrivals_until(119.98 + 0.15)        # the batch ends with the block, at 119.98 s
    assert [f.t_s for f in got] == [f.t_s for f in batch]
    p_inc, _ = error_ned_m(got)
    p_bat, _ = error_ned_m(batch)
    np.testing.assert_allclose(p_inc, p_bat, atol=1e-3)     # same noise; truth exact vs interpolated
    assert sim.fixes_until(121.0)[0].t_s == pytest.approx(120.0)     # the next epoch, none skipped


def test_lever_arm_moves_the_antenna_by_the_rotated_arm_and_adds_omega_cross_r():
    block = simulate("plane", 60.0, rate_hz=50.0, errors="ideal")
    arm = np.array([0.6, -0.4, -0.9])          # forward, left, up of the IMU (FRD)
    exact = GnssErrors(horizontal_m=0.0, vertical_m=0.0, velocity_m_s=0.0, h_acc_m=1.0, v_acc_m=1.0, s_acc_m_s=0.1)
    fixes = simulate_gnss(block, errors=exact, lever_arm_m=arm)
    idx = np.searchsorted(block.t_s, [f.t_s for f in fixes])
    assert np.allclose(block.t_s[idx], [f.t_s for f in fixes], atol=1e-9)
    c = Rotation.from_quat(np.column_stack([block.truth_q_wxyz[idx, 1:], block.truth_q_wxyz[idx, 0]]))
    w = block.truth_gyro_rad_s[idx]
    v_expected = block.truth_vel_ned_m_s[idx] + c.apply(np.cross(w, arm))
    v_got = np.array([f.vel_ned_m_s for f in fixes])
    np.testing.assert_allclose(v_got, v_expected, atol=1e-9)
    assert np.max(np.linalg.norm(v_got - block.truth_vel_ned_m_s[idx], axis=1)) > 0.1   # the turns' ω × r
    r = EARTH_RADIUS_M + block.truth_alt_m[idx]
    lat_imu = block.truth_lat_deg[idx]
    offset = np.column_stack([np.radians(np.array([f.lat_deg for f in fixes]) - lat_imu) * r,
                              np.radians(np.array([f.lon_deg for f in fixes]) - block.truth_lon_deg[idx]) * r
                              * np.cos(np.radians(lat_imu)),
                              block.truth_alt_m[idx] - np.array([f.alt_m for f in fixes])])
    np.testing.assert_allclose(offset, c.apply(arm), atol=1e-6)
    # with no noise the fix is the antenna truth itself
    p, v = error_ned_m(fixes)
    assert np.max(np.abs(p)) < 1e-6 and np.max(np.abs(v)) < 1e-12


def test_outages_drop_fixes_or_report_no_fix(boat):
    fixes = simulate_gnss(boat, outages=[(30.0, 60.0), GnssOutage(80.0, 85.0, reports_no_fix=True)])
    t = np.array([f.t_s for f in fixes])
    assert not np.any((t >= 30.0) & (t < 60.0)) and np.any(np.isclose(t, 60.0)) and np.any(np.isclose(t, 29.8))
    lost = [f for f in fixes if 80.0 <= f.t_s < 85.0]
    assert len(lost) == 25 and all(f.fix_type == GnssFixType.NO_FIX and not f.has_position for f in lost)
    assert all(f.fix_type == GnssFixType.FIX_3D for f in fixes if not 80.0 <= f.t_s < 85.0)
    # the noise at a given epoch does not depend on the outages
    clean = {f.t_s: f.lat_deg for f in simulate_gnss(boat)}
    assert all(clean[f.t_s] == f.lat_deg for f in fixes if f.fix_type == GnssFixType.FIX_3D)


def test_glitches_appear_where_configured_and_are_labelled(boat):
    glitches = [GnssGlitch(20.0, "position_jump", direction_deg=90.0),
                GnssGlitch(40.1, "velocity_spike", magnitude=4.0, direction_deg=0.0),
                GnssGlitch(60.0, "nan"), GnssGlitch(70.0, "time_backwards"),
                GnssGlitch(90.0, "position_jump", magnitude=30.0, duration_s=3.0, direction_deg=180.0)]
    fixes = simulate_gnss(boat, seed=11, glitches=glitches)
    by_t = {round(f.extra["truth"].t_s, 3): f for f in fixes}
    p, v = error_ned_m(fixes)
    t = np.array([f.extra["truth"].t_s for f in fixes])
    labelled = {round(f.extra["truth"].t_s, 3): f.extra["glitch"] for f in fixes if f.extra["glitch"]}
    assert {k: x for k, x in labelled.items() if x != "position_jump" or k < 90} == {
        20.0: "position_jump", 40.2: "velocity_spike", 60.0: "nan", 70.0: "time_backwards"}
    jump_run = [k for k, x in labelled.items() if k >= 90]
    assert jump_run == pytest.approx(np.arange(90.0, 93.01, 0.2))             # 16 fixes over 3 s
    # sizes: the noise is 1.5 m / 0.05 m/s, so a 50 m jump and a 4 m/s spike stand out by > 20 σ
    i = int(np.argmin(np.abs(t - 20.0)))
    assert p[i, 1] == pytest.approx(50.0, abs=8.0) and abs(p[i, 0]) < 8.0
    assert np.linalg.norm(p[i] - p[i - 1]) > 40.0
    i = int(np.argmin(np.abs(t - 40.2)))
    assert v[i, 0] == pytest.approx(4.0, abs=0.3) and abs(v[i, 1]) < 0.3
    run = (t >= 90.0) & (t <= 93.01)
    assert np.all(np.abs(p[run, 0] + 30.0) < 8.0)
    assert not np.isfinite(by_t[60.0].lat_deg) and not by_t[60.0].has_velocity
    back = by_t[70.0]
    assert back.t_s == pytest.approx(69.0) and back.t_s < by_t[69.8].t_s and back.extra["t_rx_s"] == pytest.approx(70.1)
    # everything else is ordinary noise
    ok = np.array([f.extra["glitch"] is None for f in fixes])
    assert np.max(np.abs(p[ok, :2])) < 6 * 1.5 and np.max(np.abs(v[ok])) < 6 * 0.05


def test_imu_samples_and_fixes_merge_in_arrival_order(boat):
    fixes = simulate_gnss(boat, glitches=[GnssGlitch(10.0, "time_backwards", magnitude=3.0)])
    items = list(in_arrival_order(boat, fixes))
    assert len(items) == len(boat) + len(fixes)
    arrival = [x.extra["t_rx_s"] if isinstance(x, GnssFix) else x.t_s for x in items]
    assert all(a <= b for a, b in zip(arrival, arrival[1:]))
    assert sum(isinstance(x, ImuSample) for x in items) == len(boat)
    first_fix = next(i for i, x in enumerate(items) if isinstance(x, GnssFix))
    # the first fix arrives at 0.1 s, the time of the 6th sample (50 Hz): it comes before that sample (a fix that has
    # arrived by a sample's time is there for it) and after the one at 0.08 s
    assert fixes[0].extra["t_rx_s"] == 0.1 and first_fix == 5
    assert items[first_fix - 1].t_s == 0.08 and items[first_fix + 1].t_s == 0.1


@pytest.mark.parametrize("kwargs, match", [
    ({"rate_hz": 0.0}, "rate_hz"), ({"latency_s": -0.1}, "latency_s"), ({"jitter_s": 0.25}, "jitter_s"),
    ({"lever_arm_m": (0, 0, float("nan"))}, "lever_arm_m"), ({"outages": [(5.0, 4.0)]}, "outage"),
])
def test_bad_configuration_is_a_clear_error(boat, kwargs, match):
    with pytest.raises(ValueError, match=match):
        simulate_gnss(boat, **kwargs)


def test_bad_error_models_and_glitches_are_rejected():
    with pytest.raises(ValueError, match="horizontal_m"):
        GnssErrors(horizontal_m=-1.0)
    with pytest.raises(ValueError, match="wander_fraction"):
        GnssErrors(wander_fraction=1.5)
    with pytest.raises(ValueError, match="h_acc_m"):
        GnssErrors(h_acc_m=0.0)
    with pytest.raises(ValueError, match="glitch kind"):
        GnssGlitch(1.0, "teleport")
    with pytest.raises(TypeError):
        simulate_gnss([1, 2, 3])
