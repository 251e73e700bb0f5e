"""The lever-arm check (estimator/lever_arm_fit.py): a wrong antenna arm is told from a wrong heading by how the
velocity innovations follow the body rate, and the rejection rule (estimator/velocity_rejection_cause.py) then
names the arm, not a heading that is only not yet known. Truth: the antenna velocity by scipy's rotation and numpy's
cross product (Groves eq. 14.123), the simulator's own antenna."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.core.estimate import HeadingState
from ahrsd.estimator.lever_arm_fit import LeverArmFit, rate_cross_ned
from ahrsd.estimator.velocity_rejection_cause import heading_rejection_cause

FIX_HZ = 5.0


def rocking(k: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """A boat's attitude (body → NED) and body rate at fix k: rolling ±8° at 0.15 Hz, pitching ±3° at 0.2 Hz,
    turning slowly, with rate noise."""
    t = k / FIX_HZ
    roll, pitch, yaw = (math.radians(8) * math.sin(2 * math.pi * 0.15 * t),
                        math.radians(3) * math.sin(2 * math.pi * 0.2 * t), 0.02 * t)
    c_bn = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()
    rate = np.array([math.radians(8) * 2 * math.pi * 0.15 * math.cos(2 * math.pi * 0.15 * t),
                     math.radians(3) * 2 * math.pi * 0.2 * math.cos(2 * math.pi * 0.2 * t), 0.02])
    return c_bn, rate + rng.normal(0.0, 0.002, 3)


def feed(fit: LeverArmFit, offset_m, seconds: float, slow_error_m_s: float, seed: int = 1,
         rejected: bool = True) -> None:
    """Innovations of an antenna `offset_m` from where the filter was told, plus a slowly wandering velocity error
    of the filter (a wrong heading turning the accelerations: a random walk, `slow_error_m_s` per √s), the
    receiver's 0.05 m/s noise, and the filter's own partial corrections at each fix (each fix `rejected` by its
    gate or not, as the filter says)."""
    rng = np.random.default_rng(seed)
    error = np.zeros(3)
    for k in range(int(seconds * FIX_HZ)):
        c_bn, rate = rocking(k, rng)
        error += rng.normal(0.0, slow_error_m_s / math.sqrt(FIX_HZ), 3)
        innovation = c_bn @ np.cross(rate, offset_m) + error + rng.normal(0.0, 0.05, 3)
        fit.add(k / FIX_HZ, innovation, rate_cross_ned(c_bn, rate), 0.05)
        correction = 0.3 * innovation          # the filter takes a part of each innovation
        error -= correction
        fit.fused(correction, rejected)


def test_rate_cross_is_the_antenna_velocity_per_metre():
    rng = np.random.default_rng(3)
    for _ in range(20):
        c_bn = Rotation.random(random_state=rng).as_matrix()
        rate, arm = rng.normal(0, 0.5, 3), rng.normal(0, 2.0, 3)
        assert rate_cross_ned(c_bn, rate) @ arm == pytest.approx(c_bn @ np.cross(rate, arm), abs=1e-12)


def test_a_wrong_arm_is_found_where_it_is_and_said_to_explain():
    offset = np.array([-1.0, 0.5, -2.0])
    fit = LeverArmFit()
    feed(fit, offset, 30.0, slow_error_m_s=0.05)
    result = fit.result()
    assert result is not None and result.explains
    assert np.all(np.abs(result.offset_m - offset) < 3 * result.sigma_m + 0.05), (result.offset_m, result.sigma_m)
    assert np.all(result.sigma_m < 1.0)


def test_a_wandering_heading_error_with_the_right_arm_is_not_the_arm():
    for seed in range(5):
        fit = LeverArmFit()
        feed(fit, np.zeros(3), 30.0, slow_error_m_s=0.3, seed=seed)
        result = fit.result()
        assert result is not None and not result.explains, (seed, result)


def test_an_arm_that_the_gate_does_not_reject_for_is_not_named():
    """The same fit with the gate rejecting nothing explains no rejection (a right arm's fit to a turning vehicle's
    own errors can come out significant; the filter is not bent beyond its noise): neither named nor latched."""
    fit = LeverArmFit()
    feed(fit, np.array([-1.0, 0.5, -2.0]), 30.0, slow_error_m_s=0.05, rejected=False)
    result = fit.result()
    assert result.chi2 > 16.27 and result.explained_share > 0.1, result
    assert not result.explains and not fit.arm_wrong


def test_an_arm_found_wrong_stays_so_until_a_fit_finds_it_right():
    """The latch: a calm spell whose fit explains less does not clear it; only a fit whose offset is not
    significant does (the arm is right after all)."""
    fit = LeverArmFit()
    feed(fit, np.array([0.0, 0.0, -2.0]), 30.0, slow_error_m_s=0.05)
    assert fit.arm_wrong
    feed(fit, np.array([0.0, 0.0, -2.0]), 30.0, slow_error_m_s=0.3, seed=2)     # swamped: explains less
    assert not fit.result().explains and fit.result().chi2 > 16.27 and fit.arm_wrong
    feed(fit, np.zeros(3), 30.0, slow_error_m_s=0.05, seed=4)
    assert fit.result().chi2 <= 16.27 and not fit.arm_wrong


def test_an_arm_error_that_a_large_heading_error_swamps_is_not_named():
    """A 2 m arm error beside a heading error that wanders 0.3 m/s per √s: the fit finds the arm significant, but
    it explains under a tenth of the innovations — the heading is what rejects the fixes."""
    fit = LeverArmFit()
    feed(fit, np.array([0.0, 0.0, -2.0]), 30.0, slow_error_m_s=0.3, seed=2)
    result = fit.result()
    assert np.sum((result.offset_m / result.sigma_m) ** 2) > 16.27, result      # significant on its own
    assert result.explained_share < 0.1 and not result.explains, result


def test_no_verdict_before_enough_fixes_nor_without_rotation():
    fit = LeverArmFit()
    feed(fit, np.array([0.0, 0.0, -4.0]), 5.0, slow_error_m_s=0.05)
    assert fit.result() is None                          # 24 differences: fewer than MIN_PAIRS
    still = LeverArmFit()
    c_bn = np.eye(3)
    for k in range(150):                                  # a vehicle that does not rotate: the arm unobservable
        still.add(k / FIX_HZ, np.random.default_rng(k).normal(0, 0.3, 3), rate_cross_ned(c_bn, np.zeros(3)), 0.05)
    assert not still.result().explains


def test_the_arm_found_overrides_a_heading_only_not_yet_trusted_but_not_an_iron_step():
    """The rule: a heading not yet known, just reset, or a magnetometer disagreeing with the GNSS yaw (which takes
    the same velocities through the same wrong arm) say nothing once the arm explains the innovations; a step of
    the iron (the gyro and magnetometer alone) still does."""
    weak = dict(mag_inconsistent=True, disagreement_rad=math.radians(70), since_yaw_reset_s=3.0, heading_unknown=True)
    assert heading_rejection_cause(**weak).key == "mag disagrees"
    assert heading_rejection_cause(**weak, lever_arm_explains=True) is None
    assert heading_rejection_cause(heading_unknown=True, lever_arm_explains=True) is None
    assert heading_rejection_cause(since_yaw_reset_s=1.0, lever_arm_explains=True) is None
    assert heading_rejection_cause(iron_step_rad=0.1, lever_arm_explains=True).key == "iron step"


@pytest.fixture(scope="module")
def boat_40s():
    from ahrsd.simulation import DEFAULT_SITE, open_stream

    stream = open_stream("boat", rate_hz=100.0, seed=0, site=DEFAULT_SITE)
    return stream, stream.next_block(4000)


def run_ins(boat_40s, told_m):
    """ins over the 40 s boat told the antenna at `told_m`: the estimator and its last estimate."""
    from ahrsd.core.sample import make_sample
    from ahrsd.estimator import make_estimator
    from ahrsd.estimator.fix_feed import GnssFixFeed
    from ahrsd.simulation import simulate_gnss

    stream, block = boat_40s
    est = make_estimator("ins", declination_rad=stream.earth_field.declination_rad, lever_arm_m=told_m)
    feed_fixes = GnssFixFeed(est, simulate_gnss(block, rate_hz=FIX_HZ, seed=1000))   # the antenna at the IMU
    for i in range(len(block.t_s)):
        feed_fixes.offer_until(block.t_s[i])
        last = est.update(make_sample(block.t_s[i], block.gyro_rad_s[i], block.accel_m_s2[i], block.mag_ut[i]))
    return est, last


def test_the_filter_finds_an_antenna_told_4_m_up_at_the_imu(boat_40s):
    """ins on a rolling simulated boat, told an antenna 4 m above the IMU that the receiver does not have: most
    velocities are rejected, the check puts the antenna back at the IMU and the heading is published unknown;
    told the right arm it says nothing and the heading is held."""
    told = (0.0, 0.0, -4.0)
    est, last = run_ins(boat_40s, told)
    result = est.lever_arm_fit()
    assert est.gnss_counters.rejected_velocity > 0.3 * est.gnss_counters.offered
    assert result.explains and np.linalg.norm(np.asarray(told) + result.offset_m) < 1.0, result
    # the heading the wrong arm bent is published unknown (σ π), not held by GNSS
    assert last.sigma_rpy_rad[2] == pytest.approx(math.pi) and last.heading_state == HeadingState.UNKNOWN
    assert last.integrity.lever_arm_wrong          # for the daemon to say why (daemon/heading_status.py)
    right_est, right_last = run_ins(boat_40s, (0.0, 0.0, 0.0))
    right = right_est.lever_arm_fit()
    assert not right.explains and np.linalg.norm(right.offset_m) < 0.5, right
    assert right_last.sigma_rpy_rad[2] < math.radians(15.0), right_last
    assert not right_last.integrity.lever_arm_wrong


def test_the_fit_is_made_when_asked_while_nothing_can_latch(monkeypatch):
    """While the gate rejects nothing and no arm is latched, a fix's `fused` makes no fit (it could change nothing:
    an arm explains only rejections), and the fit made when asked is the one made at every fix, to the bit. Counted
    by the fit's one call of np.linalg.cond. Broken (the fit made at every fix again, or the skip also while the gate
    rejects): the count during the feed is not 0, or the wrong arm is not latched."""
    import ahrsd.estimator.lever_arm_fit as module

    calls = []
    cond = np.linalg.cond
    monkeypatch.setattr(module.np.linalg, "cond", lambda a: calls.append(1) or cond(a))
    lazy = LeverArmFit()
    feed(lazy, np.array([-1.0, 0.5, -2.0]), 30.0, slow_error_m_s=0.05, rejected=False)
    assert calls == [] and not lazy.arm_wrong
    eager = LeverArmFit()
    eager_fused = eager.fused

    def fused_then_fit(correction, rejected):
        eager_fused(correction, rejected)
        eager.result()

    eager.fused = fused_then_fit
    feed(eager, np.array([-1.0, 0.5, -2.0]), 30.0, slow_error_m_s=0.05, rejected=False)
    assert len(calls) > 100
    a, b = lazy.result(), eager.result()
    assert a.offset_m.tobytes() == b.offset_m.tobytes() and a.sigma_m.tobytes() == b.sigma_m.tobytes()
    assert (a.explained_share, a.explains, a.chi2) == (b.explained_share, b.explains, b.chi2)
    rejecting = LeverArmFit()
    feed(rejecting, np.array([-1.0, 0.5, -2.0]), 30.0, slow_error_m_s=0.05)
    assert rejecting.arm_wrong
