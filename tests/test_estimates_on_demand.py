"""At 819.2 SPS the daemon builds an AttitudeEstimate only when something consumes one (the publishers at their
rates, a listener that keeps it), not after every sample — counted, not timed — while every sample still goes
through the estimator and the always-registered field calibration listener."""

from __future__ import annotations

import asyncio

import numpy as np

from ahrsd.core.sample import ImuSample, SampleFlags
from ahrsd.daemon.config import EstimatorConfig

from service_rig import gcs_socket, start_service, stop_service

RATE_HZ = 819.2
BLOCK = 4                      # samples a reader-process poll hands over at the 200 Hz tick


def _sample(k: int) -> ImuSample:
    return ImuSample(k / RATE_HZ, np.zeros(3), np.array([0.0, 0.0, -9.81]), np.array([20.0, 0.0, 40.0]), 25.0, 5.0,
                     SampleFlags.NEW_DATA, 0, k)


def _run(tmp_path, seconds: float, listener=None, in_place=False):
    """ins in the daemon (default gcs outputs), fed `seconds` of samples in blocks with a publish after each, on
    the service's running loop; returns (samples, publish ticks, estimates built (the view's count), listener calls)."""
    gcs = gcs_socket()
    service, loop = start_service(gcs, tmp_path, estimator=EstimatorConfig("ins"))
    est = service.pipeline.estimator
    view = est._view                                # ins's reused view (estimate_view.BuiltEstimateView)
    calls = []
    if listener is not None:
        service.add_sample_listener(lambda s, e: calls.append(listener(s, e)), in_place=in_place)
    n = int(seconds * RATE_HZ) // BLOCK * BLOCK

    async def feed():
        for k0 in range(0, n, BLOCK):
            block = [_sample(k) for k in range(k0, k0 + BLOCK)]
            now = block[-1].t_s
            service.reader.process(block, now)
            service.publishers.publish(now)
        await asyncio.sleep(0)

    try:
        loop.run_until_complete(feed())
        magcal_last_t = service.field_calibration.protocol._last_sample_t
        assert service.pipeline.counters.samples == n
    finally:
        stop_service(service, loop)
        gcs.close()
    return n, n // BLOCK, view.snapshots_built, calls, magcal_last_t


def test_estimates_are_built_at_the_publishers_rate_not_per_sample(tmp_path):
    n, ticks, built, _, magcal_last_t = _run(tmp_path, 3.0)
    assert magcal_last_t == (n - 1) / RATE_HZ       # the field calibration listener saw every sample
    assert 0 < built <= ticks                       # at most one per publish tick (the default outputs: ≤ 50 Hz;
    assert built < n / BLOCK                        # every output of a tick reads the one built), not every sample


def test_a_listener_that_keeps_the_estimate_gets_every_samples_immutable_one(tmp_path):
    """A listener added without `in_place` still gets, at every sample, the AttitudeEstimate of that sample."""
    n, _, built, calls, _ = _run(tmp_path, 0.5, listener=lambda s, e: (s.t_s, e.t_s, type(e).__name__))
    assert len(calls) == n and all(ts == te and name == "AttitudeEstimate" for ts, te, name in calls)
    assert built == n


def test_an_in_place_listener_costs_no_estimate(tmp_path):
    n, ticks, built, calls, _ = _run(tmp_path, 0.5, listener=lambda s, e: e.flags, in_place=True)
    assert len(calls) == n
    assert built <= ticks


def _fields(e):
    """What an estimate publishes, for exact comparison."""
    return (e.t_s, tuple(e.q_wxyz), tuple(e.sigma_rpy_rad), int(e.flags), int(e.heading_state),
            None if e.nav is None else (tuple(e.nav.vel_ned_m_s), e.nav.lat_deg, e.nav.lon_deg),
            None if e.integrity is None else repr(e.integrity))


def test_a_fix_fused_between_a_step_and_its_snapshot_does_not_change_that_samples_estimate():
    """The daemon fuses GNSS fixes between two sample blocks and builds the estimate for its outputs after that:
    the estimate is the stepped sample's as `update` built it before the fix (Ins freezes the view before a fix
    changes what the estimate reads: the first fix sets the navigation state, every fix re-checks the heading)."""
    import math

    from ahrsd.core.sample import SampleFlags, make_sample
    from ahrsd.estimator.ins import Ins

    from ins_truth import DECLINATION, gnss_fixes, simulated_run

    run = simulated_run("coordinated-turn", 20.0, rate_hz=100.0, seed=3)
    fixes = gnss_fixes(run.truth, seed=13)
    every, stepped = (Ins(declination_rad=DECLINATION, mag_calibration_sigma_rad=math.radians(0.5))
                      for _ in range(2))
    fi, compared, first_nav = 0, 0, None
    for k, t in enumerate(run.truth.t_s):
        sample = make_sample(t, run.gyro[k], run.accel[k], run.mag[k], flags=SampleFlags.NEW_DATA)
        reference = every.update(sample)
        view = stepped.step(sample)
        offered = False
        while fi < len(fixes) and fixes[fi][0] <= t:      # fixes that arrive after sample k, before k + 1
            every.update_gnss(fixes[fi][1])
            stepped.update_gnss(fixes[fi][1])
            fi += 1
            offered = True
        if offered:
            assert _fields(view.snapshot()) == _fields(reference), k
            compared += 1
            nav_set = every._nav_ok[0] > 0 and reference.nav is None     # this sample's fix set it
            first_nav = k if nav_set and first_nav is None else first_nav
    assert compared >= 90 and first_nav is not None
