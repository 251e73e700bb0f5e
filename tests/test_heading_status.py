"""The daemon says what it knows about its heading (issue 28 item 4): daemon.heading_status alone on made-up
estimates, then a simulated boat with a wrong / no magnetometer calibration through the daemon's own per-sample
path, housekeeping and VISION_POSITION_ESTIMATE builder on a stepped clock."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ahrsd.core.estimate import AttitudeEstimate, EstimateFlags, HeadingIntegrity, HeadingState
from ahrsd.daemon import messages as msgs
from ahrsd.daemon.heading_status import ANNOUNCE_AFTER_S, HeadingStatus
from ahrsd.daemon.health import Health
from ahrsd.daemon.mavlink_io import mavlink

DEG = math.radians(1.0)


def estimate(state, sigma_deg, *, disagreement_deg=math.nan, gsf_sigma_deg=2.0, gsf_valid=True, flags=0,
             with_integrity=True, mag_step_deg=math.nan, lever_arm_wrong=False):
    integrity = HeadingIntegrity(0.0, gsf_sigma_deg * DEG, gsf_valid, disagreement_deg * DEG, np.zeros(3),
                                 np.full(3, 10.0), mag_step_deg * DEG, lever_arm_wrong) if with_integrity else None
    return AttitudeEstimate(0.0, np.array([1.0, 0, 0, 0]), 0.0, 0.0, 0.0, 0.0, 0.0, np.zeros(3), np.zeros(3),
                            np.array([0.01, 0.01, sigma_deg * DEG]), EstimateFlags(flags), None,
                            HeadingState(state), integrity)


def status(cal_sigma_deg=0.5, good_deg=5.0):
    texts = []
    hs = HeadingStatus(lambda sev, text: texts.append((sev, text)), good_sigma_rad=good_deg * DEG,
                       calibration_sigma_rad=cal_sigma_deg * DEG)
    return hs, texts


def test_heading_good_only_for_the_magnetometer_or_a_small_gnss_sigma():
    cases = [(HeadingState.UNKNOWN, 0.5, False), (HeadingState.MAGNETOMETER, 1.0, True),
             (HeadingState.MAGNETOMETER, 5.1, False),
             (HeadingState.GNSS_ONLY, 4.9, True), (HeadingState.GNSS_ONLY, 5.1, False),
             (HeadingState.LEARNING, 12.0, False), (HeadingState.LEARNING, 2.0, True)]
    for state, sigma, good in cases:
        hs, _ = status()
        hs.on_estimate(estimate(state, sigma), 0.0)
        hs.on_estimate(estimate(state, sigma), ANNOUNCE_AFTER_S)
        assert hs.heading_good is good, (state, sigma)
        bits = hs.unhealthy_bits()
        assert bool(bits & msgs.SENSOR_AHRS) is (not good)
        assert bool(bits & msgs.SENSOR_MAG) is (state in (HeadingState.GNSS_ONLY, HeadingState.LEARNING))
    hs, _ = status()
    hs.on_estimate(estimate(HeadingState.MAGNETOMETER, 1.0, flags=EstimateFlags.INITIALISING), 0.0)
    assert not hs.heading_good


@pytest.mark.parametrize("cal_sigma_deg", [0.5, 10.0, math.nan], ids=["trusted", "untrusted", "none"])
def test_3d_mag_is_unhealthy_while_the_magnetometer_is_not_used_whatever_its_calibration(cal_sigma_deg):
    """GNSS-only or learning: the magnetometer is not what holds the heading, so SYS_STATUS says 3D_MAG is not
    healthy also when its calibration was never trusted (then no disagreement with the GNSS is claimed; the
    trusted case above clears the bit for that reason too)."""
    for state in (HeadingState.GNSS_ONLY, HeadingState.LEARNING):
        hs, _ = status(cal_sigma_deg=cal_sigma_deg)
        hs.on_estimate(estimate(state, 2.0), 0.0)
        assert hs.unhealthy_bits() & msgs.SENSOR_MAG, (state, cal_sigma_deg)
    hs, _ = status(cal_sigma_deg=0.5)
    hs.on_estimate(estimate(HeadingState.MAGNETOMETER, 1.0), 0.0)
    assert not hs.unhealthy_bits() & msgs.SENSOR_MAG


def test_a_magnetometer_heading_whose_sigma_widens_is_not_good_at_once_and_good_again_only_once_it_held():
    """An unaided magnetometer heading whose σ widens beyond the 5° limit for 10 s (a turn harder than the
    simulated boat's: 20 °/s at 2 m/s leans 4.1°, σ ≈ 6°), through the health report as the daemon runs it at
    10 Hz: good at once at the start (σ 1.5°), not good from the first wide estimate (MAV_STATE STANDBY, SYS_STATUS
    AHRS unhealthy, its STATUSTEXT saying why), good again only once σ held below the limit ANNOUNCE_AFTER_S."""
    from ahrsd.core.estimate import EstimateFlags as Flags
    from ahrsd.daemon.counters import ServiceCounters
    from ahrsd.daemon.housekeeping import HealthReport
    from ahrsd.daemon.outbound import Identity, Outbound
    from support.health_report_fakes import Counts, Notifier

    hs, texts = status(cal_sigma_deg=0.5)
    health = Health(stale_timeout_s=1.0)
    notifier = Notifier()
    report = HealthReport(health, Outbound(Identity(1, 200, mavlink.MAV_TYPE_IMU), ServiceCounters(),
                                           clock=lambda: 0.0), notifier, Counts(), watchdog_interval_s=None,
                          start=0.0, standby_detail=hs.standby_detail, active_detail=hs.active_detail)
    wide_from, wide_to, hold_steps = 100, 200, round(ANNOUNCE_AFTER_S / 0.1)     # in 0.1 s steps
    got = []
    for k in range(300):
        t = 0.1 * k
        health.sample_read(t)
        health.last_estimate_flags = Flags.NONE
        hs.on_estimate(estimate(HeadingState.MAGNETOMETER, 6.0 if wide_from <= k < wide_to else 1.5,
                                with_integrity=False), t)
        health.heading_good, health.heading_unhealthy_bits = hs.heading_good, hs.unhealthy_bits()
        report(t)
        ahrs_healthy = bool(health.sensor_bits(t)[2] & msgs.SENSOR_AHRS)
        got.append((hs.heading_good, ahrs_healthy, health.system_status(t) == mavlink.MAV_STATE_ACTIVE))
    expected = [(good, good, good) for good in (k < wide_from or k >= wide_to + hold_steps for k in range(300))]
    assert got == expected
    assert notifier.statuses == ["ACTIVE: heading good", "STANDBY: heading not good (mag ±6°)",
                                 "ACTIVE: heading good"]
    assert texts == [(mavlink.MAV_SEVERITY_INFO, "ahrsd: heading from magnetometer (±1.5°)")]   # one state


def test_a_gnss_held_heading_is_good_only_once_it_held_and_bad_at_once():
    hs, _ = status()
    hs.on_estimate(estimate(HeadingState.GNSS_ONLY, 2.0), 10.0)
    assert not hs.heading_good
    hs.on_estimate(estimate(HeadingState.GNSS_ONLY, 2.0), 10.0 + 0.5 * ANNOUNCE_AFTER_S)
    assert not hs.heading_good
    hs.on_estimate(estimate(HeadingState.LEARNING, 2.5), 10.0 + ANNOUNCE_AFTER_S)
    assert hs.heading_good
    hs.on_estimate(estimate(HeadingState.LEARNING, 5.5), 10.0 + ANNOUNCE_AFTER_S + 0.1)
    assert not hs.heading_good
    hs.on_estimate(estimate(HeadingState.MAGNETOMETER, 0.5), 20.0)
    assert hs.heading_good                         # the magnetometer, consistent: at once


def test_health_is_standby_with_ahrs_and_mag_unhealthy_while_the_heading_is_not_good():
    health = Health(stale_timeout_s=0.1, last_sample_time=0.0, last_estimate_flags=EstimateFlags.NONE)
    assert health.system_status(0.0) == mavlink.MAV_STATE_ACTIVE
    hs, texts = status()
    hs.on_estimate(estimate(HeadingState.LEARNING, 9.0, disagreement_deg=30.0), 0.0)
    health.heading_good, health.heading_unhealthy_bits = hs.heading_good, hs.unhealthy_bits()
    assert health.system_status(0.0) == mavlink.MAV_STATE_STANDBY
    healthy = health.sensor_bits(0.0)[2]
    assert healthy & msgs.SENSOR_GYRO and not healthy & msgs.SENSOR_AHRS and not healthy & msgs.SENSOR_MAG


def test_a_change_is_announced_with_the_disagreement_as_its_cause_once_it_held():
    hs, texts = status(cal_sigma_deg=0.5)
    hs.on_estimate(estimate(HeadingState.MAGNETOMETER, 0.6), 0.0)
    assert len(texts) == 1 and "magnetometer" in texts[0][1]
    hs.on_estimate(estimate(HeadingState.GNSS_ONLY, 3.0, disagreement_deg=-36.4), 1.0)
    assert len(texts) == 1                                  # not yet: it must hold ANNOUNCE_AFTER_S
    hs.on_estimate(estimate(HeadingState.GNSS_ONLY, 3.0, disagreement_deg=-36.4), 1.0 + ANNOUNCE_AFTER_S)
    assert len(texts) == 2
    sev, text = texts[1]
    assert sev == mavlink.MAV_SEVERITY_WARNING
    assert "magnetometer disagrees with GNSS by 36°: calibration wrong or iron changed" in text
    assert "lever" not in text
    assert hs.rejection_cause(2.0) == "mag vs GNSS 36°"
    # a flicker shorter than ANNOUNCE_AFTER_S is not announced
    hs.on_estimate(estimate(HeadingState.LEARNING, 3.0, disagreement_deg=-36.4), 10.0)
    hs.on_estimate(estimate(HeadingState.GNSS_ONLY, 3.0, disagreement_deg=-36.4), 11.0)
    hs.on_estimate(estimate(HeadingState.GNSS_ONLY, 3.0, disagreement_deg=-36.4), 20.0)
    assert len(texts) == 2


def test_a_rejection_for_an_iron_step_is_named_iron_changed_and_never_heading_good_while_it_holds():
    """ins rejected the magnetometer because its heading stepped while the gyro saw no turn (estimator/mag_step.py):
    the daemon names the iron change, its size and what holds the heading — not a disagreement with GNSS (on a
    straight leg there is no valid GNSS yaw to disagree with) — and does not say "heading good" with a GNSS σ that
    would otherwise be good; once the magnetometer re-enters (no step in the integrity) it is good again."""
    hs, texts = status(cal_sigma_deg=0.5, good_deg=5.0)
    hs.on_estimate(estimate(HeadingState.MAGNETOMETER, 0.6), 0.0)
    for t in (1.0, 1.0 + ANNOUNCE_AFTER_S, 30.0):
        hs.on_estimate(estimate(HeadingState.GNSS_ONLY, 1.0, gsf_valid=False, mag_step_deg=-4.2), t)
        assert not hs.heading_good                             # 1.0° < 5°: good, were it not a step
    assert len(texts) == 2
    sev, text = texts[1]
    assert sev == mavlink.MAV_SEVERITY_WARNING
    assert text == ("ahrsd: iron changed: mag heading stepped -4°, the gyro saw no turn; heading GNSS-held while "
                    "the iron is relearned (±1.0°, not good yet)")
    assert "disagrees" not in text
    # its first STATUSTEXT chunk alone (a receiver that does not join chunks) says what changed and by how much
    first = msgs.statustext_chunks(sev, text, 1)[0].text
    first = first.decode() if isinstance(first, bytes) else first
    assert first.rstrip("\x00") == "ahrsd: iron changed: mag heading stepped -4 deg, t"
    assert hs.status_text() == "hdg GNSS-only iron step -4° ±1.0°"
    assert hs.rejection_cause(30.0) == "mag iron step -4°"
    assert hs.unhealthy_bits() & msgs.SENSOR_MAG and hs.unhealthy_bits() & msgs.SENSOR_AHRS
    # the same GNSS-held state, the step no longer the cause (a disagreement with GNSS is): the old text, good by σ
    hs.on_estimate(estimate(HeadingState.GNSS_ONLY, 1.0, disagreement_deg=-10.4, gsf_sigma_deg=7.0), 40.0)
    hs.on_estimate(estimate(HeadingState.GNSS_ONLY, 1.0, disagreement_deg=-10.4, gsf_sigma_deg=7.0),
                   40.0 + ANNOUNCE_AFTER_S)
    assert texts[-1][1] == ("ahrsd: magnetometer disagrees with GNSS by 10°: calibration wrong or iron changed; "
                            "heading from GNSS only (±1.0°)")
    assert hs.heading_good and hs.status_text() == "hdg GNSS-only ±1.0°"
    assert hs.rejection_cause(42.0) == "mag vs GNSS 10°"


def test_a_disagreement_within_both_uncertainties_is_not_called_one():
    # while ins still uses the magnetometer: 3σ of hypot(2°, 0.5°) ≈ 6.2°; 5° is within it, 7° is not
    hs, texts = status(cal_sigma_deg=0.5)
    hs.on_estimate(estimate(HeadingState.MAGNETOMETER, 1.0, disagreement_deg=5.0), 0.0)
    assert hs.rejection_cause(0.0) is None and not hs.unhealthy_bits() & msgs.SENSOR_MAG
    hs.on_estimate(estimate(HeadingState.MAGNETOMETER, 1.0, disagreement_deg=7.0), 0.1)
    assert hs.rejection_cause(0.1) == "mag vs GNSS 7°" and hs.unhealthy_bits() & msgs.SENSOR_MAG
    # an invalid GNSS yaw never makes a disagreement
    hs, texts = status(cal_sigma_deg=0.5)
    hs.on_estimate(estimate(HeadingState.MAGNETOMETER, 1.0, disagreement_deg=40.0, gsf_valid=False), 0.0)
    assert hs.rejection_cause(0.0) is None


def test_the_calibrations_predicted_error_widens_what_counts_as_a_disagreement():
    """The same 15° against a GNSS yaw of 2°: beyond 3σ for a calibration predicting 0.5° (3·hypot(2, 0.5) ≈ 6.2°),
    within it for one predicting 10° (3·hypot(2, 10) ≈ 30.6°): the magnetometer is then as good as its
    calibration says, not wrong."""
    hs, _ = status(cal_sigma_deg=0.5)
    hs.on_estimate(estimate(HeadingState.MAGNETOMETER, 1.0, disagreement_deg=15.0), 0.0)
    assert hs.rejection_cause(0.0) == "mag vs GNSS 15°"
    hs, _ = status(cal_sigma_deg=10.0)
    hs.on_estimate(estimate(HeadingState.MAGNETOMETER, 1.0, disagreement_deg=15.0), 0.0)
    assert hs.rejection_cause(0.0) is None and not hs.mag_inconsistent


def test_a_trusted_calibration_ins_rejected_is_named_as_the_cause():
    # ins holds the heading by GNSS although the calibration claims 0.5°: it disagreed with the GNSS-held heading
    hs, texts = status(cal_sigma_deg=0.5)
    hs.on_estimate(estimate(HeadingState.GNSS_ONLY, 1.0, disagreement_deg=-10.4, gsf_sigma_deg=7.0), 0.0)
    assert "magnetometer disagrees with GNSS by 10°: calibration wrong or iron changed" in texts[-1][1]
    assert hs.rejection_cause(0.0) == "mag vs GNSS 10°"
    # a calibration that says itself it is uncertain is not "wrong"
    hs, texts = status(cal_sigma_deg=5.0)
    hs.on_estimate(estimate(HeadingState.GNSS_ONLY, 1.0, disagreement_deg=-10.4, gsf_sigma_deg=7.0), 0.0)
    assert "calibration uncertain (±5.0°)" in texts[-1][1] and hs.rejection_cause(0.0) is None


def test_without_a_calibration_the_cause_is_the_missing_calibration():
    hs, texts = status(cal_sigma_deg=math.nan)
    hs.on_estimate(estimate(HeadingState.LEARNING, 8.0, disagreement_deg=80.0), 0.0)
    assert "magnetometer disagrees with GNSS by 80°: magnetometer not calibrated" in texts[-1][1]
    assert "learning its iron" in texts[-1][1] and "not good yet" in texts[-1][1]


def test_a_magnetometer_heading_without_gnss_names_an_untrusted_calibration():
    """Without GNSS (mekf: no integrity) the calibration is the only heading reference; the estimator's σ includes
    the calibration's predicted error (estimator/calibration_heading.py). A calibration predicting more than 3°:
    the announcement is a WARNING naming it, the status line marks it, 3D_MAG is unhealthy and MAV_STATE ACTIVE
    does not say "heading good". An estimator whose σ cannot carry it (no calibration, MAGNETOMETER): the same.
    A σ beyond the 5° limit (the estimator's σ ≥ the calibration's): not good, AHRS unhealthy too, and STANDBY's
    detail names the calibration."""
    for cal_deg, caveat in ((math.nan, "mag not calibrated"), (4.0, "mag cal ±4°")):
        hs, texts = status(cal_sigma_deg=cal_deg)
        for t in (0.0, ANNOUNCE_AFTER_S):
            hs.on_estimate(estimate(HeadingState.MAGNETOMETER, 4.5, with_integrity=False), t)
        (sev, text), = texts
        assert sev == mavlink.MAV_SEVERITY_WARNING and caveat in text and "magcal" in text, text
        assert hs.status_text() == "hdg mag uncal ±4.5°"
        assert hs.active_detail() == f"heading: {caveat}"
        assert hs.unhealthy_bits() == msgs.SENSOR_MAG
        hs.on_estimate(estimate(HeadingState.MAGNETOMETER, 6.1, with_integrity=False), 2 * ANNOUNCE_AFTER_S)
        assert not hs.heading_good and hs.unhealthy_bits() == msgs.SENSOR_MAG | msgs.SENSOR_AHRS
        assert hs.standby_detail() == f"heading not good (mag ±6°, {caveat})"
    # a trusted calibration, or GNSS checking the heading (ins learns the iron): the plain announcement
    for cal_deg, integrity in ((0.5, False), (math.nan, True)):
        hs, texts = status(cal_sigma_deg=cal_deg)
        for t in (0.0, ANNOUNCE_AFTER_S):
            hs.on_estimate(estimate(HeadingState.MAGNETOMETER, 0.3, with_integrity=integrity), t)
        assert texts == [(mavlink.MAV_SEVERITY_INFO, "ahrsd: heading from magnetometer (±0.3°)")]
        assert hs.status_text() == "hdg mag ±0.3°" and hs.active_detail() == "heading good"
        assert hs.unhealthy_bits() == 0


def test_without_gnss_and_calibration_the_heading_is_unknown_and_says_why():
    """mekf with no calibration publishes σ = π (UNKNOWN): after "initialising" the cause is announced (a new cause
    of the same state is news), the status line and MAV_STATE's detail say it, 3D_MAG and AHRS are unhealthy."""
    hs, texts = status(cal_sigma_deg=math.nan)
    hs.on_estimate(estimate(HeadingState.UNKNOWN, 180.0, flags=EstimateFlags.INITIALISING, with_integrity=False), 0.0)
    assert texts[-1][1] == "ahrsd: heading unknown: initialising; no heading sent"
    for t in (1.0, 1.0 + ANNOUNCE_AFTER_S, 2.0 + ANNOUNCE_AFTER_S):
        hs.on_estimate(estimate(HeadingState.UNKNOWN, 180.0, with_integrity=False), t)
    assert len(texts) == 2, texts
    sev, text = texts[-1]
    assert sev == mavlink.MAV_SEVERITY_WARNING and text.startswith(
        "ahrsd: heading unknown: magnetometer not calibrated and no GNSS fix to check it") and "magcal" in text, text
    assert text.endswith("no heading sent")
    assert hs.status_text() == "hdg unknown uncal ±180.0°"
    assert hs.standby_detail() == "heading unknown (mag not calibrated), no heading out"
    assert not hs.heading_good and hs.unhealthy_bits() == msgs.SENSOR_MAG | msgs.SENSOR_AHRS


def test_an_uncalibrated_magnetometer_the_estimator_rejects_is_named_as_not_calibrated_not_missing():
    """The README tour's turning boat with no calibration: the estimator's norm/dip check rejects the iron-laden
    field (MAG_UNAVAILABLE). The cause announced is the missing calibration, not "no magnetometer" (a user reads
    that as a broken sensor); a calibrated magnetometer that is unavailable is still "no magnetometer"."""
    for cal_deg, expected, unexpected in ((math.nan, "magnetometer not calibrated, its field rejected", "no magnetometer"),
                                          (0.5, "no magnetometer and no GNSS yaw", "not calibrated")):
        hs, texts = status(cal_sigma_deg=cal_deg)
        for t in (1.0, 1.0 + ANNOUNCE_AFTER_S):
            hs.on_estimate(estimate(HeadingState.UNKNOWN, 180.0, flags=EstimateFlags.MAG_UNAVAILABLE,
                                    with_integrity=False), t)
        text = texts[-1][1]
        assert expected in text and unexpected not in text and text.endswith("no heading sent"), text


def test_a_calibration_that_states_no_error_is_named_as_such_not_as_missing():
    """A magnetometer calibration in force that states no heading error (an older file, fixed-yaw offsets only)
    leaves the heading as unknown as none does, but the operator is told what is true: the calibration states
    no error, not that the magnetometer is not calibrated."""
    for in_force, expected, unexpected in ((True, "magnetometer calibration states no heading error", "not calibrated"),
                                           (False, "magnetometer not calibrated", "states no")):
        texts = []
        hs = HeadingStatus(lambda sev, text: texts.append((sev, text)), good_sigma_rad=5.0 * DEG,
                           calibration_sigma_rad=math.nan, calibration_in_force=in_force)
        for t in (1.0, 1.0 + ANNOUNCE_AFTER_S):
            hs.on_estimate(estimate(HeadingState.UNKNOWN, 180.0, with_integrity=False), t)
        text = texts[-1][1]
        assert expected in text and unexpected not in text, text
        assert (hs.standby_detail() == "heading unknown (mag cal states no error), no heading out") == in_force


def test_has_mag_calibration_tells_none_from_one_without_a_figure():
    from ahrsd.calibration.heading_trust import has_mag_calibration
    from ahrsd.calibration.models import Calibration, GyroModel, MagModel

    assert not has_mag_calibration(None)
    assert not has_mag_calibration(Calibration.identity())
    assert not has_mag_calibration(Calibration.identity().with_sensor("gyro", GyroModel.identity(), method="x"))
    assert has_mag_calibration(Calibration.identity().with_sensor("mag", MagModel.identity(), method="fixed-yaw"))
    no_meta = Calibration(mag=MagModel(np.array([1.0, 0.0, 0.0]), np.eye(3)))
    assert has_mag_calibration(no_meta)


def test_the_service_tells_the_heading_status_whether_a_calibration_is_in_force(tmp_path):
    """Started on a state directory with a magnetometer calibration that states no figure, and on an empty one;
    then a calibration change to the identity (the service's calibration path)."""
    from ahrsd.calibration.models import Calibration, MagModel
    from ahrsd.calibration.store import CalibrationStore
    from ahrsd.daemon.config import EndpointConfig, EstimatorConfig
    from service_rig import gcs_socket, start_service_on, stop_service

    CalibrationStore(tmp_path / "old").save(Calibration.identity().with_sensor(
        "mag", MagModel(np.array([3.0, -2.0, 1.0]), np.eye(3)), method="older file"))
    (tmp_path / "empty").mkdir()
    for sub, in_force in (("old", True), ("empty", False)):
        svc, loop = start_service_on((EndpointConfig("udpout:127.0.0.1:9"),), tmp_path / sub,
                                     estimator=EstimatorConfig("mekf"))
        try:
            assert svc.heading_status.calibration_in_force is in_force
            assert math.isnan(svc.heading_status.calibration_sigma_rad)
            svc._on_calibration_applied(Calibration.identity())
            assert svc.heading_status.calibration_in_force is False
        finally:
            stop_service(svc, loop)


class CircleCheck:
    """What HeadingStatus reads of the estimator's circle check (estimator/field_circle.FieldCircleResult): its
    verdict on the claimed calibration variance, and the centre's offset."""

    def __init__(self, verdict, offset_ut):
        self.offset_ut = offset_ut
        self._verdict = verdict
        self.claimed = []

    def verdict(self, claimed_var_rad2):
        self.claimed.append(claimed_var_rad2)
        return self._verdict


def test_a_calibration_the_circle_finds_wrong_is_never_good_whatever_its_sigma_until_corrected():
    """Without GNSS, a calibration the circle check finds wrong (off-centre 6.3 µT) is named as such, the
    magnetometer is unhealthy and "heading good" is not said even with a small σ (1°, below the 5° limit); once
    the correction learned from the turns makes the field consistent that is said, the magnetometer stays
    unhealthy (the calibration in force is still wrong) and the heading is good again by its σ once it held. With
    GNSS the check's verdict changes nothing (ins checks the heading itself). The check is asked on the
    calibration's variance as the estimator states it (1σ 0.5°: (0.5°)², estimator/calibration_heading.py)."""
    from ahrsd.estimator.field_circle import CalibrationVerdict

    hs, texts = status(cal_sigma_deg=0.5)
    wrong = CircleCheck(CalibrationVerdict.WRONG, 6.3)
    for t in (0.0, ANNOUNCE_AFTER_S, 10.0):
        hs.on_estimate(estimate(HeadingState.MAGNETOMETER, 1.0, with_integrity=False), t, field_circle=wrong)
        assert not hs.heading_good
        assert hs.unhealthy_bits() == msgs.SENSOR_MAG | msgs.SENSOR_AHRS
    assert wrong.claimed[0] == pytest.approx((0.5 * DEG) ** 2)
    (sev, text), = texts
    assert sev == mavlink.MAV_SEVERITY_WARNING
    assert text.startswith("ahrsd: magnetometer field off-centre by 6.3 µT in turns: calibration wrong or iron "
                           "changed; heading from magnetometer (±1.0°)"), text
    assert hs.status_text() == "hdg mag uncal ±1.0°"
    corrected = CircleCheck(CalibrationVerdict.CORRECTED, 6.1)
    good = []
    for t in (12.0, 12.0 + ANNOUNCE_AFTER_S, 13.0 + ANNOUNCE_AFTER_S):
        hs.on_estimate(estimate(HeadingState.MAGNETOMETER, 1.0, with_integrity=False), t, field_circle=corrected)
        good.append(hs.heading_good)
        assert hs.unhealthy_bits() & msgs.SENSOR_MAG
    assert good == [False, True, True]
    assert "off-centre by 6.1 µT in turns: learned correction applied, recalibrate to confirm" in texts[-1][1]
    assert hs.active_detail() == "heading: mag field corrected 6.1 µT in turns"
    hs, texts = status(cal_sigma_deg=0.5)                       # with GNSS: ins checks the heading
    for t in (0.0, ANNOUNCE_AFTER_S):
        hs.on_estimate(estimate(HeadingState.MAGNETOMETER, 1.0), t, field_circle=wrong)
    assert hs.heading_good and hs.unhealthy_bits() == 0
    assert texts == [(mavlink.MAV_SEVERITY_INFO, "ahrsd: heading from magnetometer (±1.0°)")]


def test_unknown_names_why_and_says_no_heading_is_sent():
    hs, texts = status()
    hs.on_estimate(estimate(HeadingState.UNKNOWN, 30.0, flags=EstimateFlags.INITIALISING), 0.0)
    assert texts[-1][1] == "ahrsd: heading unknown: initialising; no heading sent"
    hs, texts = status()
    hs.on_estimate(estimate(HeadingState.UNKNOWN, 20.0, gsf_valid=False), 0.0)
    assert "GNSS yaw not valid yet" in texts[-1][1]
    assert hs.standby_detail() == "heading unknown, no heading out"


def test_a_heading_unknown_for_a_wrong_lever_arm_says_so_not_the_magnetometer():
    """ins publishes the heading unknown once the lever-arm check found the arm wrong (estimator/lever_arm_fit.py);
    the reason said is the arm, also while the magnetometer disagrees with the GNSS yaw the arm bent."""
    hs, texts = status(cal_sigma_deg=0.5)
    hs.on_estimate(estimate(HeadingState.UNKNOWN, 180.0, disagreement_deg=70.0, lever_arm_wrong=True), 0.0)
    assert texts[-1][1] == ("ahrsd: heading unknown: the GNSS velocities fit another antenna place than [gnss] "
                            "lever_arm_m; measure it and set it; no heading sent")
    hs, texts = status(cal_sigma_deg=0.5)
    hs.on_estimate(estimate(HeadingState.UNKNOWN, 180.0, disagreement_deg=70.0), 0.0)
    assert "lever_arm_m" not in texts[-1][1]


def test_no_yaw_reset_is_announced_while_the_arm_is_found_wrong():
    """A reset or alignment while the lever-arm check finds the arm the GNSS yaw bank takes its velocities through
    wrong (or a fitted arm not yet shown right) finds no heading: nothing says "heading reset to the GNSS yaw
    (±180°)" then (session 28's daemon did); once the arm is shown right, a reset is news again."""
    hs, texts = status(cal_sigma_deg=math.nan)
    bent = estimate(HeadingState.UNKNOWN, 180.0, lever_arm_wrong=True)
    hs.on_estimate(bent, 0.0, yaw_resets=1, gnss_yaw_alignments=1)
    hs.on_estimate(bent, 1.0, yaw_resets=2, gnss_yaw_alignments=1)
    assert not [t for _, t in texts if "GNSS yaw (" in t], texts
    hs.on_estimate(estimate(HeadingState.GNSS_ONLY, 3.0), 2.0, yaw_resets=3, gnss_yaw_alignments=1)
    assert [t for _, t in texts if "GNSS yaw (" in t] == ["ahrsd: heading reset to the GNSS yaw (±3.0°)"]


def test_each_yaw_reset_is_announced_once():
    hs, texts = status()
    e = estimate(HeadingState.MAGNETOMETER, 2.0)
    hs.on_estimate(e, 0.0, yaw_resets=1)
    hs.on_estimate(e, 1.0, yaw_resets=1)
    assert sum("reset to the GNSS yaw" in t for _, t in texts) == 1
    assert hs.rejection_cause(5.0) == "heading reset"


def test_after_the_estimator_restarts_its_first_yaw_reset_is_announced():
    """The estimator's yaw reset count starts again at 0 when it is re-initialised: its next reset (count 1) is
    news, although 1 is below the 3 already announced."""
    hs, texts = status()
    e = estimate(HeadingState.MAGNETOMETER, 2.0)
    hs.on_estimate(e, 0.0, yaw_resets=3)
    hs.on_estimate(e, 1.0, yaw_resets=0)          # re-initialised
    hs.on_estimate(e, 2.0, yaw_resets=1)
    assert sum("reset to the GNSS yaw" in t for _, t in texts) == 2


def test_the_planned_alignment_is_news_and_a_reset_of_a_wrong_heading_a_warning():
    """Without a trusted calibration ins aligns its yaw to the first valid GNSS yaw (a plan, as PX4 EKF2 does):
    INFO, not the WARNING of a heading that was found wrong and reset."""
    hs, texts = status(cal_sigma_deg=math.nan)
    e = estimate(HeadingState.GNSS_ONLY, 3.0)
    hs.on_estimate(e, 0.0, yaw_resets=1, gnss_yaw_alignments=1)
    hs.on_estimate(e, 1.0, yaw_resets=1, gnss_yaw_alignments=1)
    assert [(sev, "aligned" in t) for sev, t in texts if "GNSS yaw (" in t] == [(mavlink.MAV_SEVERITY_INFO, True)]
    hs.on_estimate(e, 2.0, yaw_resets=2, gnss_yaw_alignments=1)      # then a reset of a heading found wrong
    resets = [(sev, t) for sev, t in texts if "GNSS yaw (" in t]
    assert len(resets) == 2 and resets[1][0] == mavlink.MAV_SEVERITY_WARNING and "reset to the GNSS yaw" in resets[1][1]


# ------------------------------------------------------------------------------ the daemon on a simulated boat

RATE_HZ = 200.0


def _boat(seconds, seed):
    """A boat's raw samples (its vehicle iron in the field), the magnetometer model that calibrates them
    exactly, its GNSS fixes (5 Hz) and the declination."""
    from ahrsd.calibration.models import MagModel
    from ahrsd.simulation import GnssErrors, SensorErrors, open_stream, simulate_gnss

    stream = open_stream("boat", rate_hz=RATE_HZ, seed=seed, errors=SensorErrors.adis16405(seed))
    block = stream.next_block(int(seconds * RATE_HZ))
    err = stream.errors
    fixes = simulate_gnss(block, rate_hz=5.0, seed=seed + 1000,
                          errors=GnssErrors(horizontal_m=1.5, vertical_m=2.5, velocity_m_s=0.05), latency_s=0.1)
    fixes.sort(key=lambda f: f.extra["t_rx_s"])
    return block, MagModel(err.hard_iron_ut, np.linalg.inv(err.soft_iron)), fixes, stream.earth_field.declination_rad


def _true_heading_errors_deg(q_est_true, q_truth):
    from scipy.spatial.transform import Rotation

    def yaw(q):
        return Rotation.from_quat(np.roll(np.asarray(q), -1, axis=-1)).as_euler("ZYX")[..., 0]

    return np.degrees((yaw(q_est_true) - yaw(q_truth) + np.pi) % (2 * np.pi) - np.pi)


class Text(str):
    def __new__(cls, text, state, sigma_rad):
        out = super().__new__(cls, text)
        out.state, out.sigma_rad = state, sigma_rad
        return out


def run_daemon_on_boat(tmp_path, hard_iron_error_ut=None, *, seconds=150.0, seed=3, estimator="ins", gnss=True):
    """The boat through a started Service (ins, or `estimator`): the per-sample path, the GNSS fixes (unless
    `gnss` is False) into the estimator,
    housekeeping's heading status at 10 Hz and the publishers, on a stepped clock (the sample time). Returns
    the VISION_POSITION_ESTIMATEs (with the estimate each was built from and the truth then) and the texts."""
    import dataclasses

    from ahrsd.core.sample import SampleFlags, make_sample
    from ahrsd.daemon.config import EndpointConfig, EstimatorConfig, LocationConfig
    from bench.sim_calibration import save_mag_calibration
    from service_rig import gcs_socket, start_service_on, stop_service

    from ahrsd.calibration.models import MagModel

    block, true_model, fixes, decl = _boat(seconds, seed)
    fixes = fixes if gnss else []
    if hard_iron_error_ut is not None:       # a calibration that says 0.5° but misses part of the hard iron
        wrong = MagModel(true_model.hard_iron_ut + np.asarray(hard_iron_error_ut, float), true_model.soft_iron)
        save_mag_calibration(tmp_path, wrong)
    mag = block.mag_ut
    gcs = gcs_socket()
    now_s = [0.0]   # the daemon's clock, stepped to each sample's time (Outbound's STATUSTEXT rate limit runs on it)
    svc, loop = start_service_on((EndpointConfig(f"udpout:127.0.0.1:{gcs.getsockname()[1]}"),), tmp_path,
                                 clock=lambda: now_s[0], estimator=EstimatorConfig(estimator),
                                 location=LocationConfig(declination_deg=math.degrees(decl)))
    hs = svc.heading_status
    # every message the endpoint sent (its traffic-log hook: the frames as packed) with the estimate, and the
    # heading state and yaw 1σ, when it was sent
    sent = []
    parser = mavlink.MAVLink(None)
    svc.endpoints[0].traffic_log = lambda frame: sent.extend(
        (m, svc.pipeline.last_estimate, hs.state, hs.sigma_rad) for m in parser.parse_buffer(frame) or ())
    svc.listeners.fns.clear()                # (the field calibration needs the running loop; not used here)
    try:
        est = svc.pipeline.estimator
        fi, next_hk = 0, 0.0
        truth_at = {}
        for k in range(len(block.t_s)):
            t = now_s[0] = float(block.t_s[k])
            while fi < len(fixes) and fixes[fi].extra["t_rx_s"] <= t:
                est.update_gnss(fixes[fi])
                fi += 1
            s = make_sample(t, block.gyro_rad_s[k], block.accel_m_s2[k], mag[k], flags=SampleFlags.NEW_DATA,
                            counter=k)
            svc.reader.process((s,), t)
            n = len(sent)                        # every message sent at this sample gets its truth
            if t >= next_hk:                     # housekeeping's first two jobs at 10 Hz
                next_hk = t + 0.1
                svc._update_heading_status(t)
                svc.health_report(t)
            svc.publishers.publish(t)
            for _ in range(len(sent) - n):
                truth_at[len(truth_at)] = block.truth_q_wxyz[k]
    finally:
        stop_service(svc, loop)
        gcs.close()
    vpe = [(m, e, truth_at[i]) for i, (m, e, _, _) in enumerate(sent)
           if m.get_msgId() == mavlink.MAVLINK_MSG_ID_VISION_POSITION_ESTIMATE]
    return vpe, _statustexts(sent), svc, decl


def _statustexts(sent) -> list[Text]:
    """The STATUSTEXTs among the messages sent, as Texts (the chunks of one text, which go out together, joined)."""
    texts, chunked = [], {}
    for m, _, state, sigma_rad in sent:
        if m.get_msgId() != mavlink.MAVLINK_MSG_ID_STATUSTEXT:
            continue
        if m.id == 0:
            texts.append(Text(m.text, state, sigma_rad))
        elif m.id in chunked:
            chunked[m.id].append(m.text)
        else:
            chunked[m.id] = parts = [m.text]
            texts.append((parts, state, sigma_rad))      # joined below, in the order they were sent
    return [t if isinstance(t, Text) else Text("".join(t[0]), t[1], t[2]) for t in texts]


@pytest.fixture(scope="module")
def uncalibrated_boat(tmp_path_factory):
    return run_daemon_on_boat(tmp_path_factory.mktemp("uncal"), None, seconds=120.0)


@pytest.fixture(scope="module")
def wrongly_calibrated_boat(tmp_path_factory):
    # 60 s: its texts (the rejection, the states after it) are all said by then (docs/testing.md "Session 36 (cia)")
    return run_daemon_on_boat(tmp_path_factory.mktemp("wrong"), (12.0, -8.0, 0.0), seconds=60.0)


def test_without_gnss_no_calibration_sends_no_heading_and_a_good_one_a_small_honest_variance(tmp_path):
    """mekf, no GNSS, the boat's iron in the field (its uncalibrated heading is tens of degrees off): with no
    calibration the heading is unknown, no VISION_POSITION_ESTIMATE is sent and the daemon says why; with the
    calibration that removes the iron exactly, stating 0.5°, the VPE's yaw variance is the estimator's σ², at least
    (0.5°)², and covers the error against the simulator's truth."""
    vpe, texts, svc, _ = run_daemon_on_boat(tmp_path / "none", None, seconds=40.0, estimator="mekf", gnss=False)
    assert vpe == []
    assert any("magnetometer not calibrated and no GNSS fix to check it" in t for t in texts), texts
    assert svc.heading_status.unhealthy_bits() & msgs.SENSOR_MAG
    assert svc.heading_status.status_text().startswith("hdg unknown uncal")
    vpe, texts, svc, _ = run_daemon_on_boat(tmp_path / "good", (0.0, 0.0, 0.0), seconds=40.0, estimator="mekf",
                                            gnss=False)
    assert vpe and all(e.heading_state == HeadingState.MAGNETOMETER for _, e, _ in vpe)
    for m, e, _ in vpe:
        assert m.covariance[20] == pytest.approx(float(e.sigma_rpy_rad[2]) ** 2, rel=1e-6)
        assert m.covariance[20] >= math.radians(0.5) ** 2 * (1 - 1e-9)
    t, err, sigma = _vpe_errors(vpe)
    _print_figures("boat, mekf, no GNSS, exact calibration stating 0.5 deg", t, err, sigma)
    late = t >= 20.0
    assert np.mean(np.abs(err[late]) <= 3.0 * sigma[late]) >= 0.99
    assert np.median(sigma[late]) < 5.0
    assert svc.heading_status.unhealthy_bits() == 0


def _vpe_errors(vpe):
    from scipy.spatial.transform import Rotation

    t = np.array([m.usec * 1e-6 for m, _, _ in vpe])
    yaw = np.array([m.yaw for m, _, _ in vpe])
    true_yaw = Rotation.from_quat(np.roll(np.array([q for _, _, q in vpe]), -1, axis=1)).as_euler("ZYX")[:, 0]
    err = np.degrees((yaw - true_yaw + np.pi) % (2 * np.pi) - np.pi)
    sigma = np.degrees(np.sqrt([m.covariance[20] for m, _, _ in vpe]))
    return t, err, sigma


def _print_figures(case, t, err, sigma):
    """The VPE the autopilot got against the simulator's truth (pytest -s shows it; docs/daemon.md)."""
    print(f"\n{case}: first VPE at {t[0]:.1f} s; {len(t)} VPEs")
    for start in (0.0, 30.0, 60.0, 90.0):
        w = t >= start
        if w.any():
            print(f"  from {start:3.0f} s: yaw RMS {np.sqrt(np.mean(err[w] ** 2)):.2f} deg, median sigma "
                  f"{np.median(sigma[w]):.2f} deg, beyond 3 sigma {100 * np.mean(np.abs(err[w]) > 3 * sigma[w]):.1f} %")


def test_no_vpe_while_the_heading_is_unknown_and_its_variance_is_the_estimators(uncalibrated_boat):
    vpe, texts, svc, _ = uncalibrated_boat
    assert vpe, "no VISION_POSITION_ESTIMATE at all"
    assert all(e.heading_state != HeadingState.UNKNOWN for _, e, _ in vpe)
    assert vpe[0][0].usec * 1e-6 > 5.0           # the uncalibrated start is UNKNOWN: nothing sent then
    for m, e, _ in vpe:                           # the yaw variance is the estimator's, never clamped
        assert m.covariance[20] == pytest.approx(float(e.sigma_rpy_rad[2]) ** 2, rel=1e-6)
    t, err, sigma = _vpe_errors(vpe)
    late = t >= 30.0
    _print_figures("boat, no calibration", t, err, sigma)
    assert np.mean(np.abs(err[late]) <= 3.0 * sigma[late]) >= 0.99   # against the simulator's truth


def test_an_uncalibrated_magnetometer_is_named_and_heading_good_waits_for_gnss(uncalibrated_boat):
    vpe, texts, svc, _ = uncalibrated_boat
    joined = " | ".join(texts)
    assert "magnetometer not calibrated" in joined and "lever" not in joined
    good = [t for t in texts if t.endswith("heading good")]
    # "heading good" only while the GNSS holds the heading within the limit (the magnetometer is never trusted)
    assert good and all(t.state in (HeadingState.GNSS_ONLY, HeadingState.LEARNING)
                        and t.sigma_rad <= math.radians(5.0) for t in good)
    assert all(t.state != HeadingState.MAGNETOMETER for t in texts)


def test_a_wrong_calibration_is_rejected_named_and_reported_unhealthy(wrongly_calibrated_boat):
    vpe, texts, svc, _ = wrongly_calibrated_boat
    # the rejection is named and the heading status leaves the magnetometer (learning its iron, then GNSS only); the
    # VPEs need not show it: the GNSS-only yaw σ is about 3° (INITIALISING above it, no VPE) right after the rejection
    # and 12–14° from 25 s (a VPE with that state came only in a 1 s window where the σ was within 0.01° under 3°)
    rejected = [i for i, t in enumerate(texts) if "calibration wrong or iron changed" in t]
    assert rejected
    assert {HeadingState.GNSS_ONLY, HeadingState.LEARNING} <= {t.state for t in texts[rejected[0]:]}
    assert all(e.heading_state != HeadingState.UNKNOWN for _, e, _ in vpe)
    for m, e, _ in vpe:
        assert m.covariance[20] == pytest.approx(float(e.sigma_rpy_rad[2]) ** 2, rel=1e-6)
    _print_figures("boat, calibration missing (12, -8, 0) uT of hard iron, claiming 0.5 deg", *_vpe_errors(vpe))


def _vpe_builder_service(tmp_path):
    from ahrsd.daemon.config import EndpointConfig
    from service_rig import start_service_on

    svc, loop = start_service_on((EndpointConfig("udpout:127.0.0.1:9"),), tmp_path)
    svc.health.last_sample_time, svc.health.last_estimate_flags = 1.0, EstimateFlags.NONE   # trusted sensor
    return svc, loop


def test_the_vpe_builder_withholds_an_unknown_heading_even_when_the_sensor_is_fine(tmp_path):
    from ahrsd.daemon.output_registry import BY_MESSAGE_ID
    from service_rig import stop_service

    svc, loop = _vpe_builder_service(tmp_path)
    try:
        build = BY_MESSAGE_ID[mavlink.MAVLINK_MSG_ID_VISION_POSITION_ESTIMATE].build
        assert svc.health.heading_trusted(1.0)
        # gyro-only after the magnetometer went (mekf MAG_UNAVAILABLE): no INITIALISING, but nobody knows the heading
        assert build(svc, estimate(HeadingState.UNKNOWN, 8.0, flags=EstimateFlags.MAG_UNAVAILABLE), None, 1.0) is None
        m = build(svc, estimate(HeadingState.GNSS_ONLY, 8.0), None, 1.0)
        assert m is not None and m.covariance[20] == pytest.approx(math.radians(8.0) ** 2, rel=1e-6)
        # a known heading, but the estimator initialising, or the sensor failed: not for the autopilot either
        svc.health.last_estimate_flags = EstimateFlags.INITIALISING
        assert build(svc, estimate(HeadingState.MAGNETOMETER, 1.0, flags=EstimateFlags.INITIALISING), None, 1.0) is None
        svc.health.last_estimate_flags = EstimateFlags.NONE
        svc.health.sensor_error = "bus failure"
        assert build(svc, estimate(HeadingState.MAGNETOMETER, 1.0), None, 1.0) is None
        svc.health.sensor_error = ""
        assert build(svc, estimate(HeadingState.MAGNETOMETER, 1.0), None, 1.0) is not None
    finally:
        stop_service(svc, loop)


def test_a_yaw_reset_of_the_estimator_leaves_reset_counter_alone(tmp_path):
    """ins slews a reset into the yaw it publishes (estimator/published_heading.py): nothing steps, so nothing is
    announced to the autopilot as a reset (ArduPilot reads reset_counter as a position reset)."""
    from ahrsd.daemon.output_registry import BY_MESSAGE_ID
    from service_rig import stop_service

    svc, loop = _vpe_builder_service(tmp_path)
    try:
        build = BY_MESSAGE_ID[mavlink.MAVLINK_MSG_ID_VISION_POSITION_ESTIMATE].build
        svc.pipeline.estimator.yaw_resets = 0        # the counter ins keeps (Ins.yaw_resets)
        e = estimate(HeadingState.GNSS_ONLY, 2.0)
        first = build(svc, e, None, 1.0).reset_counter
        svc.pipeline.estimator.yaw_resets = 1        # ins reset its yaw to the GNSS yaw (EstimateFlags.YAW_RESET)
        after = []
        for k in range(1, 4):
            svc.health.last_sample_time = now = 1.0 + 0.1 * k
            after.append(build(svc, e, None, now).reset_counter)
        assert after == [first] * 3
    finally:
        stop_service(svc, loop)


def test_the_calibrations_predicted_heading_error_reaches_ins_as_a_figure_or_unknown():
    from ahrsd.calibration.models import Calibration, MagModel
    from ahrsd.calibration.heading_trust import calibration_heading_sigma_rad

    model = MagModel(np.array([3.0, -2.0, 1.0]), np.eye(3))
    cal = Calibration.identity().with_sensor
    assert math.degrees(calibration_heading_sigma_rad(cal("mag", model, heading_std_deg=0.3, offset_std_deg=0.4))) \
        == pytest.approx(0.5)
    # the field session's undetermined offset (null), no figure at all, no calibration: unknown
    assert math.isnan(calibration_heading_sigma_rad(cal("mag", model, heading_std_deg=0.3, offset_std_deg=None)))
    assert math.isnan(calibration_heading_sigma_rad(cal("mag", model, method="fixed-yaw")))
    assert math.isnan(calibration_heading_sigma_rad(Calibration.identity()))
    # a negative figure is no figure (a corrupt or hand-edited file): unknown, not its magnitude
    assert math.isnan(calibration_heading_sigma_rad(cal("mag", model, heading_std_deg=-0.3, offset_std_deg=0.4)))
    # `ahrsd calibrate mag`: the field residual over WMM's horizontal field at the fit site (Boulder, H ≈ 21 µT)
    from ahrsd.core.wmm import earth_field

    h = earth_field(40.0, -105.0).horizontal_ut
    got = calibration_heading_sigma_rad(cal("mag", model, residual_rms_ut=0.5,
                                            site={"lat_deg": 40.0, "lon_deg": -105.0, "alt_m": 0.0}))
    assert got == pytest.approx(math.atan2(0.5, h))


def test_rejected_velocities_while_the_heading_is_unknown_are_the_headings_not_the_lever_arms():
    """The rule `calibrate mag --gnss` shares (estimator/velocity_rejection_cause.py): a filter that has not found
    its heading rejects correct fixes; the GNSS task's "lever arm?" is for a heading that is known. While
    initialising nothing is said of it (no heading yet, no fixes fused)."""
    hs, _ = status()
    hs.on_estimate(estimate(HeadingState.UNKNOWN, 60.0, gsf_valid=False), 0.0)
    assert hs.rejection_cause(0.0) == "heading unknown"
    hs.on_estimate(estimate(HeadingState.MAGNETOMETER, 1.0, gsf_valid=False), 1.0)
    assert hs.rejection_cause(1.0) is None
    hs, _ = status()
    hs.on_estimate(estimate(HeadingState.UNKNOWN, 60.0, gsf_valid=False, flags=EstimateFlags.INITIALISING), 0.0)
    assert hs.rejection_cause(0.0) is None


def test_initialising_soon_after_a_calibration_change_is_its_convergence_and_later_a_restart_again():
    """INITIALISING within a second of a calibration change (the swap widened the heading past convergence) is said
    as converging on it; an estimate taken before the swap (not initialising) does not end the wait; INITIALISING
    long after a change (an estimator restarted) is "initialising" again."""
    hs, _texts = status()
    hs.on_estimate(estimate(HeadingState.MAGNETOMETER, 1.0), 10.0)
    hs.set_calibration_sigma(0.4 * DEG, in_force=True)                      # the swap, between two ticks
    hs.on_estimate(estimate(HeadingState.MAGNETOMETER, 1.0), 10.2)         # the estimate from before it
    hs.on_estimate(estimate(HeadingState.MAGNETOMETER, 12.0, flags=EstimateFlags.INITIALISING), 10.4)
    assert hs.standby_detail() == "heading converging on the new calibration, no heading out"
    hs.on_estimate(estimate(HeadingState.MAGNETOMETER, 2.0), 11.0)
    hs.on_estimate(estimate(HeadingState.MAGNETOMETER, 12.0, flags=EstimateFlags.INITIALISING), 30.0)
    assert hs.standby_detail() == "initialising, no heading out"
    hs.set_calibration_sigma(0.4 * DEG, in_force=True)                      # a change whose estimate never widens
    hs.on_estimate(estimate(HeadingState.MAGNETOMETER, 1.0), 30.5)
    hs.on_estimate(estimate(HeadingState.MAGNETOMETER, 12.0, flags=EstimateFlags.INITIALISING), 40.0)
    assert hs.standby_detail() == "initialising, no heading out"
