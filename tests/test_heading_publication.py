"""ins's heading publication alone (estimator/heading_publication.py, HeadingPublication), built without a filter
around a real heading monitor whose verdicts are set by hand: the heading state at the checks (UNKNOWN above the
unknown σ, LEARNING/GNSS_ONLY while the kernel's field check still rejects a magnetometer the monitor let back,
the hold before a better state), the state an estimate carries from its flags, the integrity record and the report.
The expected states are the rules written out by hand (docs/gnss.md "Heading state"), not the part's output. The
filter hands its monitor at each call (a new calibration replaces it): the tests keep it as `part.monitor`."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from ahrsd.core.estimate import EstimateFlags, HeadingState
from ahrsd.estimator.heading_monitor import HeadingMonitor
from ahrsd.estimator.heading_publication import HeadingPublication
from ahrsd.estimator.ins import Ins, InsParams

DEG = math.pi / 180.0
HOLD_S = 5.0
UNKNOWN_SIGMA = 15.0 * DEG
KNOWN_SIGMA = 12.0 * DEG
MAG_UNAVAILABLE_S = 4.0
TRUSTED = 3.0 * DEG
AIDED = int(EstimateFlags.GNSS_AIDED)
INITIALISING = int(EstimateFlags.INITIALISING)
IRON = np.array([1.0, -2.0, 0.5])
IRON_SIGMA = np.array([0.1, 0.2, 0.3])


def _part(heading_monitor: bool = True, mag_enabled: bool = True):
    params = SimpleNamespace(heading_unknown_sigma_rad=UNKNOWN_SIGMA, heading_known_sigma_rad=KNOWN_SIGMA,
                             heading_state_hold_s=HOLD_S, mag_unavailable_s=MAG_UNAVAILABLE_S, init_min_time_s=1.0,
                             heading_monitor=heading_monitor, mag_enabled=mag_enabled)
    monitor = HeadingMonitor(10.0 * DEG, trusted_sigma_rad=TRUSTED)
    part = HeadingPublication(params)
    part.monitor = monitor    # the tests' handle on it: the filter hands its monitor at each call
    return part, monitor


def _check(part, t_s, sigma_deg=2.0, trust_deg=1.0, since_update_s=0.0, bent=False, gsf_var=(4 * DEG) ** 2):
    part.publish(t_s, part.monitor, sigma_deg * DEG, 0.3, gsf_var, True, (trust_deg * DEG) ** 2, since_update_s,
                 IRON, IRON_SIGMA, bent)
    return part.state


def _published(part, f, sigma_rad, t_run_s, mag_use):
    return part.published(f, sigma_rad, np.array([t_run_s]), np.array([mag_use]), part.monitor)


def _note_step(part, t_s, step_rad):
    part.note_step_rejection(t_s, step_rad, part.monitor.mag_rejected)


def test_ins_params_are_what_the_part_judges_with():
    p = InsParams()
    part = HeadingPublication(p)
    assert part.state == HeadingState.UNKNOWN and part.integrity is None
    assert part.published(AIDED, p.heading_unknown_sigma_rad * 1.01, np.array([10.0]), np.array([1.0]),
                          SimpleNamespace(mag_rejected=False)) == HeadingState.UNKNOWN


def test_unknown_while_the_sigma_is_above_the_unknown_limit():
    part, _ = _part()
    for t in range(20):
        assert _check(part, float(t), sigma_deg=15.5) == HeadingState.UNKNOWN
    # a σ between the known (12°) and the unknown (15°) limits does not leave UNKNOWN either
    for t in range(20, 40):
        assert _check(part, float(t), sigma_deg=13.0) == HeadingState.UNKNOWN
    # known (σ 2°, after the hold), then a σ above the unknown limit at a check: UNKNOWN at that check
    for t in range(40, 50):
        _check(part, float(t))
    assert part.state == HeadingState.MAGNETOMETER
    assert _check(part, 50.0, sigma_deg=15.5) == HeadingState.UNKNOWN


def test_a_better_state_is_published_only_once_it_held_at_the_check_rate():
    part, _ = _part()
    states = [_check(part, 0.2 * k) for k in range(30)]    # checks at 5 Hz, a trusted magnetometer from t = 0
    t_first = 0.2 * states.index(HeadingState.MAGNETOMETER)
    assert math.isclose(t_first, HOLD_S, abs_tol=1e-9)
    assert all(s == HeadingState.UNKNOWN for s in states[:states.index(HeadingState.MAGNETOMETER)])
    # worse at once: an untrusted magnetometer (variance above the monitor's trusted σ) is GNSS-held at this check
    assert _check(part, 6.0, trust_deg=5.0) == HeadingState.GNSS_ONLY


def test_a_magnetometer_the_kernel_still_rejects_is_learning_or_gnss_only():
    for learning, expected in ((True, HeadingState.LEARNING), (False, HeadingState.GNSS_ONLY)):
        part, monitor = _part()
        monitor.learning = learning
        # the monitor lets it back (not rejected, trusted) but the kernel fused no field for 4.5 s > 4 s
        states = [_check(part, 0.2 * k, since_update_s=4.5) for k in range(40)]
        assert states[-1] == expected
        assert HeadingState.MAGNETOMETER not in states
        # a field fused within mag_unavailable_s: the magnetometer holds it (after the hold)
        states = [_check(part, 8.0 + 0.2 * k, since_update_s=MAG_UNAVAILABLE_S) for k in range(30)]
        assert states[-1] == HeadingState.MAGNETOMETER


def test_a_rejected_magnetometer_leaves_the_gnss_holding_the_heading():
    part, monitor = _part()
    for k in range(30):
        _check(part, 0.2 * k)
    assert part.state == HeadingState.MAGNETOMETER
    monitor.mag_rejected = True
    assert _check(part, 6.2) == HeadingState.GNSS_ONLY


def test_the_state_an_estimate_carries_follows_its_flags():
    part, monitor = _part()
    monitor.learning = True
    for k in range(40):
        _check(part, 0.2 * k, since_update_s=10.0)
    assert part.state == HeadingState.LEARNING
    s = 5.0 * DEG
    assert _published(part, AIDED, s, 10.0, 1.0) == HeadingState.LEARNING
    assert _published(part, AIDED, 15.5 * DEG, 10.0, 1.0) == HeadingState.UNKNOWN          # σ above the limit
    assert _published(part, AIDED | INITIALISING, s, 10.0, 1.0) == HeadingState.LEARNING   # GNSS-held, run 10 s
    assert _published(part, AIDED | INITIALISING, s, 0.5, 1.0) == HeadingState.UNKNOWN     # before init_min_time_s
    assert _published(part, INITIALISING, s, 10.0, 1.0) == HeadingState.UNKNOWN            # not aided
    # unaided: the magnetometer alone, trusted only in use and not rejected
    assert _published(part, 0, s, 10.0, 1.0) == HeadingState.MAGNETOMETER
    assert _published(part, 0, s, 10.0, 0.0) == HeadingState.UNKNOWN
    monitor.mag_rejected = True
    assert _published(part, 0, s, 10.0, 1.0) == HeadingState.UNKNOWN
    # without the heading monitor an aided estimate claims the magnetometer
    plain, _ = _part(heading_monitor=False)
    assert _published(plain, AIDED, s, 10.0, 1.0) == HeadingState.MAGNETOMETER
    assert _published(plain, AIDED | INITIALISING, s, 10.0, 1.0) == HeadingState.UNKNOWN
    nomag, _ = _part(mag_enabled=False)
    assert _published(nomag, 0, s, 10.0, 1.0) == HeadingState.UNKNOWN


def test_the_integrity_record_and_the_report():
    part, monitor = _part()
    monitor.disagreement_rad = 0.25
    _note_step(part, 3.0, 0.4)
    monitor.mag_rejected = True
    _check(part, 3.0, bent=True)
    i = part.integrity
    assert (i.gsf_yaw_rad, i.gsf_valid, i.mag_disagreement_rad) == (0.3, True, 0.25)
    assert math.isclose(i.gsf_sigma_rad, 4 * DEG)
    assert np.array_equal(i.iron_offset_ut, IRON) and np.array_equal(i.iron_sigma_ut, IRON_SIGMA)
    assert i.mag_step_rad == 0.4 and i.lever_arm_wrong
    _note_step(part, 3.2, math.nan)     # still rejected: the step it is rejected for is still named
    _check(part, 3.2, gsf_var=math.nan)
    assert part.integrity.mag_step_rad == 0.4 and math.isnan(part.integrity.gsf_sigma_rad)
    _note_step(part, 5.0, 0.6)          # a second step: the report keeps the first
    monitor.mag_rejected = False
    _note_step(part, 9.0, math.nan)     # re-entered: no step any more
    _check(part, 9.0)
    assert math.isnan(part.integrity.mag_step_rad) and not part.integrity.lever_arm_wrong
    monitor.rejections, monitor.max_disagreement_rad = 2, 0.5
    r = part.report(monitor, yaw_resets=3)
    assert (r.mag_rejections, r.yaw_resets, r.first_step_t_s) == (2, 3, 3.0)
    assert math.isclose(r.max_disagreement_deg, math.degrees(0.5))
    assert math.isclose(r.first_step_deg, math.degrees(0.4))
    assert r.mag_steps == monitor.step.detections


def test_the_filter_hands_the_monitor_a_new_calibration_built():
    """Ins.set_mag_calibration_sigma replaces the filter's heading monitor while the publication goes on: what is
    published reads the monitor in force, not the one the publication was built beside."""
    est = Ins(mag_calibration_sigma_rad=5.0 * DEG)
    est.set_mag_calibration_sigma(2.0 * DEG)
    est._heading.monitor.rejections, est._heading.monitor.mag_rejected = 4, True
    assert est.heading_report().mag_rejections == 4
