"""The learned iron's bookkeeping, the part alone (estimator/iron_in_use.py), built without a filter: what counts as
learned; a restored iron and a forgotten one; a new calibration's prior reaching only a learner that has learned
nothing; the learning step's span (the first counts one check, 0.2 s) and the window's yaw share it grows; and the
kernel's field reference taken from the WMM field while an iron is learned and forgotten after. The expected values
are written out by hand from the rules (the field's magnitude and dip from its components, the share's first step
from the gain, the inflation from the span), not read from the part."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from ahrsd.estimator.heading_monitor import N_IRON
from ahrsd.estimator.iron_in_use import IronInUse
from ahrsd.estimator.mag_heading import MAG_HEADING_STATE_DTYPE

PRIOR_UT, SOFT_PRIOR = 30.0, 0.1
FIELD_NED_UT = np.array([20.0, 5.0, 40.0])
TAU_S, UNMODELLED_UT = 5.0, 1.5


def _level(yaw_rad: float) -> np.ndarray:
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _measured(yaw_rad: float, offset_ut=(8.0, -4.0, 3.0)) -> np.ndarray:
    return _level(yaw_rad).T @ FIELD_NED_UT + np.asarray(offset_ut)


def _learn(iron: IronInUse, t_s: float, yaw_rad: float, yaw_var_rad2: float = 1e-4) -> None:
    iron.learn(t_s, _measured(yaw_rad), _level(yaw_rad), FIELD_NED_UT, np.eye(3) * 1e-4, yaw_var_rad2,
               UNMODELLED_UT, TAU_S)


def _mag_state():
    return np.zeros(1, MAG_HEADING_STATE_DTYPE)[0]


def test_learned_after_a_step_or_a_restore_not_after_forgetting():
    iron = IronInUse(PRIOR_UT, SOFT_PRIOR)
    assert not iron.learned and not iron.restored
    _learn(iron, 1.0, 0.3)
    assert iron.learned and not iron.restored
    iron.forget()
    assert not iron.learned
    assert np.array_equal(iron.learner.cov, np.diag([PRIOR_UT ** 2] * 3 + [SOFT_PRIOR ** 2] * 9))
    iron.restore([1.0, 2.0, 3.0], np.eye(3) * 4.0)
    assert iron.learned and iron.restored and iron.learner.updates == 0
    assert np.array_equal(iron.learner.offset_ut, [1.0, 2.0, 3.0])
    iron.forget()
    assert not iron.learned and not iron.restored and not np.any(iron.learner.state)


def test_a_restored_iron_starts_without_a_window_yaw_share():
    iron = IronInUse(PRIOR_UT, SOFT_PRIOR)
    for k in range(5):
        _learn(iron, 0.2 * k, 0.4 * k, yaw_var_rad2=1e-3)
    assert np.any(iron.yaw_share.share)
    iron.restore([1.0, 2.0, 3.0], np.eye(3) * 4.0)
    assert not np.any(iron.yaw_share.share)


def test_a_new_calibrations_prior_reaches_only_a_learner_that_learned_nothing():
    fresh = IronInUse(PRIOR_UT, SOFT_PRIOR)
    fresh.new_calibration(0.02)
    assert np.allclose(np.diag(fresh.learner.cov)[3:], 0.02 ** 2, rtol=0.0, atol=0.0)
    learned = IronInUse(PRIOR_UT, SOFT_PRIOR)
    _learn(learned, 1.0, 0.3)
    state, cov = learned.learner.state.copy(), learned.learner.cov.copy()
    share = learned.yaw_share.share.copy()
    learned.new_calibration(0.02)
    assert learned.learner.soft_prior_sigma == 0.02          # taken at its reset
    assert np.array_equal(learned.learner.state, state) and np.array_equal(learned.learner.cov, cov)
    assert np.array_equal(learned.yaw_share.share, share)
    restored = IronInUse(PRIOR_UT, SOFT_PRIOR)
    restored.restore([1.0, 2.0, 3.0], np.eye(3) * 4.0)
    restored.new_calibration(0.02)
    assert np.array_equal(restored.learner.offset_ut, [1.0, 2.0, 3.0])


@pytest.mark.parametrize("second_after_s", [0.2, 1.0, 10.0])
def test_a_step_inflates_the_attitude_noise_by_tau_over_its_span_the_first_counting_one_check(second_after_s):
    iron = IronInUse(PRIOR_UT, SOFT_PRIOR)
    twin = copy.deepcopy(iron.learner)
    _learn(iron, 3.0, 0.3)
    twin.update(_measured(0.3), _level(0.3), FIELD_NED_UT, np.eye(3) * 1e-4, UNMODELLED_UT, TAU_S / 0.2)
    # t − (t − 0.2) is 0.2 within rounding: equal to 1e-12, where a wrong span moves the covariance by percents
    assert np.allclose(iron.learner.state, twin.state, rtol=1e-12, atol=0.0)
    assert np.allclose(iron.learner.cov, twin.cov, rtol=1e-12, atol=1e-15)
    _learn(iron, 3.0 + second_after_s, 1.1)
    twin.update(_measured(1.1), _level(1.1), FIELD_NED_UT, np.eye(3) * 1e-4, UNMODELLED_UT,
                max(1.0, TAU_S / second_after_s))
    assert np.allclose(iron.learner.cov, twin.cov, rtol=1e-9, atol=1e-15)
    assert iron.last_t_s == 3.0 + second_after_s


def test_the_first_step_puts_the_gain_times_the_yaw_sigma_into_the_share():
    iron = IronInUse(PRIOR_UT, SOFT_PRIOR)
    _learn(iron, 1.0, 0.3, yaw_var_rad2=0.0025)
    k, _, j = iron.learner.last_gain
    assert iron.yaw_share.share.shape == (N_IRON,)
    assert np.allclose(iron.yaw_share.share, k @ j[:, 2] * 0.05, rtol=1e-12, atol=0.0)
    s = iron.yaw_share.share
    assert np.allclose(iron.harmonic_cov(), iron.learner.cov + np.outer(s, s), rtol=1e-12, atol=0.0)
    assert np.any(np.outer(s, s))


def test_the_field_reference_is_the_wmm_fields_while_an_iron_is_learned_and_forgotten_after():
    norm = math.sqrt(20.0 ** 2 + 5.0 ** 2 + 40.0 ** 2)
    dip = math.atan2(40.0, math.sqrt(20.0 ** 2 + 5.0 ** 2))
    iron = IronInUse(PRIOR_UT, SOFT_PRIOR)
    ms = _mag_state()
    ms["ref_norm_ut"], ms["ref_dip_rad"] = 50.0, 1.0          # the kernel's own, from the first field
    iron.follow_field_reference(ms, FIELD_NED_UT)             # nothing learned: the kernel's stays
    assert ms["ref_norm_ut"] == 50.0 and ms["ref_dip_rad"] == 1.0
    iron.restore([1.0, 2.0, 3.0], np.eye(3) * 4.0)
    iron.follow_field_reference(ms, None)                      # no WMM field: the kernel's stays
    assert ms["ref_norm_ut"] == 50.0
    iron.follow_field_reference(ms, FIELD_NED_UT)
    assert ms["ref_norm_ut"] == pytest.approx(norm, rel=1e-12) and ms["cand_norm_ut"] == ms["ref_norm_ut"]
    assert ms["ref_dip_rad"] == pytest.approx(dip, rel=1e-12) and ms["cand_dip_rad"] == ms["ref_dip_rad"]
    ms["gate_open_s"] = 7.0
    iron.forget()
    iron.follow_field_reference(ms, FIELD_NED_UT)
    assert ms["ref_norm_ut"] == 0.0 and ms["ref_dip_rad"] == 0.0 and ms["gate_open_s"] == 0.0   # the next field sets it
    ms["ref_norm_ut"] = 50.0
    iron.follow_field_reference(ms, FIELD_NED_UT)               # forgotten once: a reference set since stays
    assert ms["ref_norm_ut"] == 50.0
