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
from ahrsd.estimator.lever_arm_fit import RATE_MEAN_S, LeverArmFit
from ahrsd.estimator.velocity_rejection_cause import heading_rejection_cause
from lever_arm_reference import mean_rate, rate_cross_ned

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
    gate or not, as the filter says). The innovations are taken at the arm the check has the filter use (the told
    one plus what it adopted, `correction_m`)."""
    rng = np.random.default_rng(seed)
    error = np.zeros(3)
    for k in range(int(seconds * FIX_HZ)):
        c_bn, rate = rocking(k, rng)
        error += rng.normal(0.0, slow_error_m_s / math.sqrt(FIX_HZ), 3)
        innovation = c_bn @ np.cross(rate, offset_m - fit.correction_m) + error + rng.normal(0.0, 0.05, 3)
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
    significant does (the arm is right after all), while the gate fuses the fixes as a right arm lets it — not
    while it still rejects them (a fit over a filter whose heading wandered far is its own error, not the arm's).
    Every consumer reads the latch (`result().arm_wrong`, `heading_bent`), not the momentary `explains`."""
    fit = LeverArmFit()
    feed(fit, np.array([0.0, 0.0, -2.0]), 30.0, slow_error_m_s=0.05)
    assert fit.arm_wrong and not fit.adoptions     # not sure enough of it to adopt it (σ against 2 m)
    feed(fit, np.array([0.0, 0.0, -2.0]), 30.0, slow_error_m_s=0.3, seed=2)     # swamped: explains less
    result = fit.result()
    assert not result.explains and result.chi2 > 16.27 and fit.arm_wrong
    assert result.arm_wrong and result.heading_bent          # what the daemon, replay and the rule read
    feed(fit, np.zeros(3), 30.0, slow_error_m_s=0.05, seed=4)                    # still rejecting: held
    assert fit.result().chi2 <= 16.27 and fit.arm_wrong
    feed(fit, np.zeros(3), 30.0, slow_error_m_s=0.05, seed=4, rejected=False)
    assert fit.result().chi2 <= 16.27 and not fit.arm_wrong and not fit.result().heading_bent


def test_a_fitted_arm_is_adopted_once_sure_and_trusted_once_the_gate_fuses_again():
    """The heading back: the check adopts the error it fits only once its 1σ is small against it (not at the first
    fit that explains, 1.1 m against 3.7); the arm in use is then told + fitted, near the antenna; the heading stays
    bent (`heading_bent`) while the gate still rejects, and is trusted once a full window of fixes is fused as a
    right arm lets it be. The told arm stays found wrong: the configuration is the operator's."""
    offset = np.array([-2.0, 1.0, -3.0])
    fit = LeverArmFit()
    feed(fit, offset, 10.0, slow_error_m_s=0.05)
    assert fit.arm_wrong and fit.result().explains and fit.adoptions == 0 and fit.heading_bent
    assert fit.correction_m.tolist() == [0.0, 0.0, 0.0]
    feed(fit, offset, 20.0, slow_error_m_s=0.05, seed=2)
    assert fit.adoptions >= 1 and np.linalg.norm(fit.correction_m - offset) < 0.5, fit.correction_m
    assert fit.arm_in_use((0.1, 0.0, 0.0)) == pytest.approx(np.array([0.1, 0, 0]) + fit.correction_m)
    feed(fit, offset, 20.0, slow_error_m_s=0.05, seed=3)                  # the gate still rejects: held
    assert fit.heading_bent and fit.result().arm_adopted
    feed(fit, offset, 19.0, slow_error_m_s=0.05, seed=4, rejected=False)  # 95 fused: 5 rejected still in the window
    assert fit.heading_bent
    feed(fit, offset, 2.0, slow_error_m_s=0.05, seed=5, rejected=False)
    assert not fit.heading_bent and fit.arm_wrong and fit.result().arm_wrong
    assert np.linalg.norm(fit.result().antenna_m((0.0, 0.0, 0.0)) - offset) < 0.5


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


def test_the_rejection_rule_reads_the_latch_not_the_momentary_fit():
    """The rejections counted by cause (velocity_rejection_watch.py, replay's summary and `calibrate mag --gnss`)
    read the arm as the heading does: a calm window whose fit explains less leaves the arm the cause of a rejection
    before a heading not yet found, while the latch holds."""
    from types import SimpleNamespace

    from ahrsd.core.estimate import AttitudeEstimate, EstimateFlags
    from ahrsd.estimator.lever_arm_fit import LeverArmFitResult
    from ahrsd.estimator.velocity_rejection_watch import UNEXPLAINED, RejectionWatch

    fit = LeverArmFitResult(np.array([-1.0, 0.0, -2.0]), np.full(3, 0.3), 0.05, False, 5.0, arm_wrong=True,
                            heading_bent=True)
    counters = SimpleNamespace(rejected_velocity=0)
    est = SimpleNamespace(yaw_resets=0, gnss_counters=counters, lever_arm_fit=lambda: fit,
                          params=SimpleNamespace(heading_unknown_sigma_rad=math.radians(30.0)))
    unknown = AttitudeEstimate(1.0, np.array([1.0, 0, 0, 0]), 0.0, 0.0, 0.0, 0.0, 0.0, np.zeros(3), np.zeros(3),
                               np.array([0.01, 0.01, math.pi]), EstimateFlags(0), None, HeadingState.UNKNOWN, None)
    watch = RejectionWatch(est, mag_enabled=True)
    counters.rejected_velocity = 3
    watch(unknown)
    assert watch.by_cause == {UNEXPLAINED: 3}             # the arm's, not "heading unknown"
    fit = fit._replace(arm_wrong=False, heading_bent=False, explains=True)    # latch off: the heading's
    counters.rejected_velocity = 5
    watch(unknown)
    assert watch.by_cause == {UNEXPLAINED: 3, "heading unknown": 2}


def weaving(k: int, rng, speed_m_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A car or a plane weaving through turns: its attitude (body → NED), body rate (with rate noise) and velocity
    (NED) at fix k. The yaw rate swings ±0.25 rad/s over 16 s; the body rolls with the lateral acceleration (0.02 rad
    per m/s², a car on its springs, a plane banking less than coordinated), so the rotation is about the vertical
    almost only."""
    t = k / FIX_HZ
    w = 2 * math.pi / 16.0
    yaw_rate, yaw = 0.25 * math.sin(w * t), -0.25 / w * math.cos(w * t) + 0.01 * t
    roll, roll_rate = 0.02 * speed_m_s * yaw_rate, 0.02 * speed_m_s * 0.25 * w * math.cos(w * t)
    c_bn = Rotation.from_euler("ZYX", [yaw, 0.0, roll]).as_matrix()
    velocity = speed_m_s * np.array([math.cos(yaw), math.sin(yaw), 0.0])
    return c_bn, np.array([roll_rate, 0.0, yaw_rate]) + rng.normal(0.0, 0.002, 3), velocity


def feed_weaving(fit: LeverArmFit, offset_m, seconds: float, heading_error_rad: float, speed_m_s: float = 15.0,
                 seed: int = 1, rejected: bool = True, reset: tuple[float, float] | None = None) -> None:
    """Innovations of a weaving vehicle (`weaving`) whose filter holds a heading `heading_error_rad` off: the
    velocity it integrates is the true change turned by that error (Groves eq. 14.69's specific-force term), so its
    velocity error follows the turns' accelerations; plus an antenna `offset_m` from where it was told, the
    receiver's 0.05 m/s noise and the filter's partial corrections, each fix `rejected` or not. The filter's own
    velocity (NED) goes with each innovation, as ins gives it. `reset` (time s, heading error after, rad): the
    filter's yaw reset at that fix, as ins's `_reset_yaw` does: its heading error another from then on, its velocity
    set to the fix, and the fit told (`heading_reset`)."""
    rng = np.random.default_rng(seed)
    turn = Rotation.from_euler("z", heading_error_rad).as_matrix()
    error, last_velocity = np.zeros(3), None          # error: true − filter velocity, NED m/s
    for k in range(int(seconds * FIX_HZ)):
        if reset is not None and k == round(reset[0] * FIX_HZ):
            turn, error = Rotation.from_euler("z", reset[1]).as_matrix(), np.zeros(3)
            fit.heading_reset()
        c_bn, rate, velocity = weaving(k, rng, speed_m_s)
        if last_velocity is not None:
            error += (np.eye(3) - turn) @ (velocity - last_velocity)
        last_velocity = velocity
        innovation = c_bn @ np.cross(rate, np.asarray(offset_m) - fit.correction_m) + error + rng.normal(0.0, 0.05, 3)
        fit.add(k / FIX_HZ, innovation, rate_cross_ned(c_bn, rate), 0.05, velocity - error)
        correction = 0.3 * innovation
        error -= correction
        fit.fused(correction, rejected)


@pytest.mark.parametrize("speed_m_s", [15.0, 50.0])
def test_a_right_arm_is_not_found_wrong_while_the_heading_is_far_off(speed_m_s):
    """A car or a plane starting with its heading not yet known (100° off, as the uncalibrated plane at the
    held-back places starts) and its gate rejecting the fixes: the velocity error the wrong heading makes follows
    the turns' accelerations, which follow the yaw rate, and the fit models it (the heading's columns) instead of
    taking it for an arm: the right arm is never found wrong, and the fit puts the antenna within its own 3σ of
    the IMU. Broken (the heading's part not modelled): the residual the heading leaves swamps the arm (no direction
    observed), and main's fit found the right arm wrong here at 100°."""
    fit = LeverArmFit(adopt=True)
    feed_weaving(fit, np.zeros(3), 60.0, math.radians(100.0), speed_m_s=speed_m_s)
    result = fit.result()
    assert not fit.arm_wrong and not fit.adoptions, result
    assert result.directions >= 2, result            # the fit judged the horizontal arm: it did not shrug
    assert result.chi2 < 16.27 and float(result.offset_m @ np.linalg.pinv(result.cov_m2) @ result.offset_m) < 16.27


def test_a_wrong_arm_is_found_beside_a_heading_far_off():
    """The heading's columns do not hide an arm: 2.5 m aft and 1 m to the side, 100° of heading error, the arm is
    found where it is (within 3σ of its fit and 0.5 m) on the weaving car."""
    offset = np.array([-2.5, 1.0, 0.0])
    fit = LeverArmFit(adopt=False)
    feed_weaving(fit, offset, 30.0, math.radians(100.0))
    result = fit.result()
    assert result.explains and fit.arm_wrong, result
    assert np.all(np.abs(result.offset_m[:2] - offset[:2]) < np.minimum(3 * result.sigma_m[:2], 0.5)), result


def test_a_right_arm_is_not_found_wrong_across_a_yaw_reset():
    """A car whose heading, 100° off, is reset to the GNSS yaw (3° off) halfway through the fit's window, its
    velocity set to the fix: the pairs before the reset hold one heading error, those after another, and a single
    heading error over the window leaves the difference to the arm (the uncalibrated plane at Nairobi had its right
    arm found wrong at 14.3 s, just after its two alignment resets). With each reset starting another attitude error
    (`heading_reset`) the right arm is not found wrong and the fit puts it within its 3σ of the told one. Broken
    (one attitude error over the window): found wrong."""
    fit = LeverArmFit(adopt=False)
    feed_weaving(fit, np.zeros(3), 20.0, math.radians(100.0), reset=(10.0, math.radians(3.0)))
    result = fit.result()
    assert not fit.arm_wrong, result
    assert result.directions >= 2 and float(result.offset_m @ np.linalg.pinv(result.cov_m2) @ result.offset_m) < 16.27


def test_a_wrong_arm_is_found_across_a_yaw_reset():
    """A reset does not throw away what the pairs before it say of the arm: the plane (50 m/s) 100° off, reset to
    3° off at 10 s, its antenna 2.5 m aft and 1 m to the side: found wrong, within 3σ of its fit (and 0.6 m)
    horizontally. Broken (one attitude error over the window, or no reset told): not found."""
    offset = np.array([-2.5, 1.0, 0.0])
    fit = LeverArmFit(adopt=False)
    feed_weaving(fit, offset, 30.0, math.radians(100.0), speed_m_s=50.0, reset=(10.0, math.radians(3.0)))
    result = fit.result()
    assert fit.arm_wrong and result.explains, result
    assert np.all(np.abs(result.offset_m[:2] - offset[:2]) < np.minimum(3 * result.sigma_m[:2], 0.6)), result


def test_the_arms_rate_is_the_gyros_mean_about_the_fix():
    """The arm's term takes the body rate as the gyro's mean over RATE_MEAN_S about the fix (`mean_rate`): one
    sample's noise (0.5°/s, an ADIS16405 at 204.8 SPS), doubled by the differencing, is of the size of the rocking
    boat's roll-rate change between fixes, and a regressor that noisy shrinks the fitted arm towards zero. The mast
    (1 m aft, 2 m up) on the rocking boat, 20 s: found within its 3σ on every axis (2 m up fitted 1.86 ± 0.33 m).
    Broken (one sample's rate): 1.19 m up, beyond its 3σ."""
    rng = np.random.default_rng(7)
    fit = LeverArmFit(adopt=False)
    offset, sample_s = np.array([-1.0, 0.0, -2.0]), 1.0 / 204.8
    w_roll, w_pitch = 2 * math.pi * 0.15, 2 * math.pi * 0.2
    for k in range(int(20.0 * FIX_HZ)):
        t = k / FIX_HZ
        rows_t = t + sample_s * np.arange(-40, 41)
        rates = np.column_stack([math.radians(8) * w_roll * np.cos(w_roll * rows_t),
                                 math.radians(3) * w_pitch * np.cos(w_pitch * rows_t), np.full(len(rows_t), 0.02)])
        c_bn = Rotation.from_euler("ZYX", [0.02 * t, math.radians(3) * math.sin(w_pitch * t),
                                           math.radians(8) * math.sin(w_roll * t)]).as_matrix()
        innovation = c_bn @ np.cross(rates[40], offset) + rng.normal(0.0, 0.05, 3)
        gyro = rates + rng.normal(0.0, math.radians(0.5), rates.shape)
        fit.add(t, innovation, rate_cross_ned(c_bn, mean_rate(rows_t, gyro, t, gyro[40])), 0.05)
        fit.fused(np.zeros(3), True)
    result = fit.result()
    assert result.explains and result.directions == 3, result
    assert np.all(np.abs(result.offset_m - offset) < 3 * result.sigma_m), result


def test_mean_rate_is_numpys_mean_of_the_rows_within_the_span_to_the_bit():
    """`mean_rate` adds the rows within RATE_MEAN_S in Python floats: the same value to the bit as numpy's mean of
    those rows (the mask over them, `sum(axis=0) / len`), which is what the filter's output was made with, for row
    counts up to a few hundred (819.2 SPS over a wide span), a column of −0.0 (numpy's sum starts from +0.0), the rows
    in either time order (the history is read newest first) and no row within the span (the rate at the fix)."""
    rng = np.random.default_rng(11)
    for k in list(range(0, 40)) + [64, 127, 128, 129, 300]:
        t = np.sort(rng.uniform(0.0, 0.3, k))
        rows = rng.normal(0.0, 0.3, (k, 3)) * 10.0 ** rng.integers(-4, 2, (k, 1))
        if k % 3 == 0:
            rows[:, 1] = -0.0
        for order in (slice(None), slice(None, None, -1)):
            t_s = float(rng.uniform(0.0, 0.3))
            at = rng.normal(0.0, 0.3, 3)
            near = np.abs(t[order] - t_s) <= 0.5 * RATE_MEAN_S
            want = rows[order][near].sum(axis=0) / near.sum() if near.any() else at
            assert mean_rate(t[order], rows[order], t_s, at).tobytes() == want.tobytes(), (k, t_s)


def test_directions_the_rotation_does_not_observe_stay_at_the_told_arm():
    """A vehicle turning about its vertical only (no roll: a flat car) observes the arm's horizontal place, not its
    height: told a height 2 m wrong, the fit leaves the height at the told arm (its σ the prior's) and puts no
    lateral offset in its place. Broken (every direction fitted): the height is fitted from the jitter of the roll
    and pitch."""
    rng = np.random.default_rng(5)
    fit = LeverArmFit(adopt=False)
    offset = np.array([0.0, 0.0, -2.0])
    for k in range(150):
        t = k / FIX_HZ
        yaw_rate = 0.25 * math.sin(2 * math.pi * t / 16.0)
        c_bn = Rotation.from_euler("z", -0.25 * 16.0 / (2 * math.pi) * math.cos(2 * math.pi * t / 16.0)).as_matrix()
        # a flat car: its roll and pitch only jitter (0.0007 rad/s), leaving the height's 1σ near the car's 3.6 m
        rate = np.array([0.0, 0.0, yaw_rate]) + rng.normal(0.0, [0.0007, 0.0007, 0.002])
        # the filter's own slowly wandering velocity error (a heading error it corrects), and the receiver's noise
        innovation = c_bn @ np.cross(rate, offset) + rng.normal(0.0, 0.05, 3) + 0.2 * math.sin(0.3 * t)
        fit.add(t, innovation, rate_cross_ned(c_bn, rate), 0.05)
        fit.fused(np.zeros(3), True)
    result = fit.result()
    assert result.directions == 2 and abs(result.offset_m[2]) < 0.01, result
    assert result.sigma_m[2] == pytest.approx(fit.prior_sigma_m, rel=0.01)
    assert np.all(np.abs(result.offset_m[:2]) < 0.5), result


@pytest.fixture(scope="module")
def boat_40s():
    from ahrsd.simulation import DEFAULT_SITE, open_stream

    stream = open_stream("boat", rate_hz=100.0, seed=0, site=DEFAULT_SITE)
    return stream, stream.next_block(4000)


def run_ins(boat, told_m, antenna_m=(0.0, 0.0, 0.0), adopt: bool = True, each=None, estimates_from: int = 0):
    """ins over a simulated boat (stream, block) told the antenna at `told_m`, the receiver's at `antenna_m`: the
    estimator and its last estimate; `each(est, estimate, i)` after every sample; `adopt` False: the lever-arm
    check never adopts the arm it fits. The samples before `estimates_from` are stepped without building their
    estimate (`each` gets None; estimator/estimate_view.py: building none changes none)."""
    from ahrsd.core.sample import make_sample
    from ahrsd.estimator import make_estimator
    from ahrsd.estimator.fix_feed import GnssFixFeed
    from ahrsd.simulation import simulate_gnss

    stream, block = boat
    est = make_estimator("ins", declination_rad=stream.earth_field.declination_rad, lever_arm_m=told_m,
                         lever_arm_adopt=adopt)
    feed_fixes = GnssFixFeed(est, simulate_gnss(block, rate_hz=FIX_HZ, seed=1000, lever_arm_m=antenna_m))
    n = len(block.t_s)
    assert estimates_from < n
    for i in range(n):
        feed_fixes.offer_until(block.t_s[i])
        view = est.step(make_sample(block.t_s[i], block.gyro_rad_s[i], block.accel_m_s2[i], block.mag_ut[i]))
        last = view.snapshot() if i >= estimates_from else None
        if each is not None:
            each(est, last, i)
    return est, last


def test_the_filter_finds_an_antenna_told_4_m_up_at_the_imu(boat_40s):
    """ins on a rolling simulated boat, told an antenna 4 m above the IMU that the receiver does not have: the
    check puts the antenna back at the IMU, and the heading is published unknown while the arm in use is found
    wrong or the fitted one not yet shown right; told the right arm it says nothing and the heading is held."""
    told = (0.0, 0.0, -4.0)
    seen = []
    est, last = run_ins(boat_40s, told, each=lambda e, out, i: seen.append(
        (e.lever_arm_fit() is not None and e.lever_arm_fit().heading_bent, out.sigma_rpy_rad[2], out.heading_state,
         out.integrity is not None and out.integrity.lever_arm_wrong)))
    result = est.lever_arm_fit()
    assert result.arm_wrong and np.linalg.norm(result.antenna_m(told)) < 1.0, result
    bent = [s for s in seen if s[0]]
    # the heading the wrong arm bent is published unknown (σ π), not held by GNSS, and said why (the daemon's words,
    # daemon/heading_status.py); the fitted arm, once shown right, lets it be found again
    assert bent and all(s[1] == pytest.approx(math.pi) and s[2] == HeadingState.UNKNOWN and s[3] for s in bent)
    assert result.arm_adopted and not result.heading_bent and not last.integrity.lever_arm_wrong
    right_est, right_last = run_ins(boat_40s, (0.0, 0.0, 0.0), estimates_from=len(boat_40s[1].t_s) - 1)
    right = right_est.lever_arm_fit()
    assert not right.explains and not right.arm_wrong and np.linalg.norm(right.offset_m) < 0.5, right
    assert not right.arm_adopted and right_est._lever_arm_fit.correction_m.tolist() == [0.0, 0.0, 0.0]
    assert right_last.sigma_rpy_rad[2] < math.radians(15.0), right_last
    assert not right_last.integrity.lever_arm_wrong


@pytest.fixture(scope="module")
def boat_120s():
    from ahrsd.simulation import DEFAULT_SITE, open_stream

    stream = open_stream("boat", rate_hz=100.0, seed=0, site=DEFAULT_SITE)
    return stream, stream.next_block(12000)


MAST_M = (-1.0, 0.0, -2.0)       # the receiver's antenna on a mast, 1 m aft and 2 m up (body FRD)


def true_yaw_error_rad(stream, block, i: int, estimate) -> float:
    """The published (magnetic) yaw less the simulator's true one at sample i, wrapped, rad."""
    q = block.truth_q_wxyz[i]
    true_yaw = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_euler("ZYX")[0]
    d = estimate.yaw_rad + stream.earth_field.declination_rad - true_yaw
    return (d + math.pi) % (2 * math.pi) - math.pi


def test_no_yaw_reset_from_a_bank_fed_through_an_arm_found_wrong(boat_120s):
    """The GNSS yaw bank took the velocities through the same arm as the filter: while the check finds that arm
    wrong, that yaw is bent as the filter's, and resetting the yaw to it would publish a bent heading as found (main
    reset the mast boat's yaw to it 4× in 240 s). Blocking the resets instead let the filter's yaw, held by nothing,
    wander far enough to spoil the fit (the daemon on the 90 s mast boat then fitted the mast 1.3 m *down*). So the
    bank takes them through the arm the check found (told + its last explaining fit) until the filter adopts one.
    With the adoption off, on the mast boat told no arm: every reset while the arm is found wrong comes from a bank
    fed through an arm within 0.7 m of the mast, and the heading stays unknown."""
    seen = []
    # the estimator's state at every sample, the estimate at the last only
    est, last = run_ins(boat_120s, (0.0, 0.0, 0.0), MAST_M, adopt=False, each=lambda e, out, i: seen.append(
        (e.yaw_resets, e._lever_arm_fit.in_use_wrong, e._gsf_par["lever_arm_m"].copy())),
        estimates_from=len(boat_120s[1].t_s) - 1)
    latched = [k for k, (_, wrong, _) in enumerate(seen) if wrong]
    assert latched and latched[0] < 1000                     # found wrong within 10 s
    resets_while_wrong = [arm for k in range(latched[0] + 1, len(seen))
                          for n, wrong, arm in [seen[k]] if wrong and n != seen[k - 1][0]]
    assert resets_while_wrong, "no reset to check on this run"
    for arm in resets_while_wrong:
        assert np.linalg.norm(arm - MAST_M) < 0.7, arm      # main: the told (0, 0, 0), 2.2 m off
    assert last.heading_state == HeadingState.UNKNOWN and last.integrity.lever_arm_wrong


def test_the_fitted_arm_is_adopted_and_the_heading_found_again(boat_120s):
    """The mast boat told no arm: once the check is sure of the error it fits, the filter and the GNSS yaw bank
    fuse at told + fitted arm; the heading stays unknown until the adopted arm leaves the gate rejecting as a right
    arm does, then is found again, its σ covering its error against the simulator's truth."""
    stream, block = boat_120s
    out = []
    est, last = run_ins(boat_120s, (0.0, 0.0, 0.0), MAST_M, each=lambda e, o, i: out.append(
        (true_yaw_error_rad(stream, block, i, o), o.sigma_rpy_rad[2], e._lever_arm_fit.heading_bent)))
    result = est.lever_arm_fit()
    assert result.arm_wrong and result.arm_adopted                        # the told arm stays found wrong
    assert np.linalg.norm(result.antenna_m((0.0, 0.0, 0.0)) - MAST_M) < 0.4, result
    assert np.linalg.norm(est._fusion.arm_in_use() - MAST_M) < 0.4                # what the filter fuses with
    assert np.linalg.norm(est.lever_arm_adopted_m() - MAST_M) < 0.4                # what the daemon says, no fit
    err, sigma, bent = (np.array(c) for c in zip(*out))
    known = ~bent & (sigma < est.params.heading_unknown_sigma_rad)
    assert known[-3000:].all(), "the heading was not found again with the fitted arm"
    assert np.all(np.abs(err[known]) <= 3.0 * sigma[known])                # σ covers the error once known
    assert math.degrees(np.sqrt(np.mean(err[-3000:] ** 2))) < 1.0         # the last 30 s
    assert est.gnss_counters.rejected_velocity < 0.05 * est.gnss_counters.offered


def test_by_default_the_fitted_arm_is_not_adopted_and_the_heading_stays_unknown(boat_120s):
    """`lever_arm_adopt` is off by default (estimator/ins.py InsParams): the mast boat told no arm is found wrong and
    its heading published unknown to the end, fused at the told arm — not at a fitted one (a fit made while an
    uncalibrated plane's heading was still unknown was once sure of arms of tens of metres, docs/gnss.md)."""
    from ahrsd.core.sample import make_sample
    from ahrsd.estimator import make_estimator
    from ahrsd.estimator.fix_feed import GnssFixFeed
    from ahrsd.simulation import simulate_gnss

    stream, block = boat_120s
    est = make_estimator("ins", declination_rad=stream.earth_field.declination_rad, lever_arm_m=(0.0, 0.0, 0.0))
    feed_fixes = GnssFixFeed(est, simulate_gnss(block, rate_hz=FIX_HZ, seed=1000, lever_arm_m=MAST_M))
    sigmas = []
    for i in range(len(block.t_s)):
        feed_fixes.offer_until(block.t_s[i])
        view = est.step(make_sample(block.t_s[i], block.gyro_rad_s[i], block.accel_m_s2[i], block.mag_ut[i]))
        if i >= len(block.t_s) - 3000:       # the estimates read: the last 30 s
            sigmas.append(view.snapshot().sigma_rpy_rad[2])
    result = est.lever_arm_fit()
    assert result.arm_wrong and not result.arm_adopted, result
    assert np.array_equal(est._fusion.arm_in_use(), np.zeros(3))                  # fused at the told arm
    assert est.lever_arm_adopted_m() is None
    assert np.all(np.array(sigmas[-3000:]) >= est.params.heading_unknown_sigma_rad)   # unknown to the end


def test_the_fit_is_made_when_asked_while_nothing_can_latch(monkeypatch):
    """While the gate rejects nothing and no arm is latched, a fix's `fused` makes no fit (it could change nothing:
    an arm explains only rejections), and the fit made when asked is the one made at every fix, to the bit. Counted
    by the fit's one call of np.linalg.eigh. Broken (the fit made at every fix again, or the skip also while the gate
    rejects): the count during the feed is not 0, or the wrong arm is not latched."""
    import ahrsd.estimator.lever_arm_fit as module

    calls = []
    eigh = np.linalg.eigh
    monkeypatch.setattr(module.np.linalg, "eigh", lambda a: calls.append(1) or eigh(a))
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

