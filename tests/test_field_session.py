"""FieldCalibration session on synthetic data with known hard/soft iron (truth from scipy, not estimator maths)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from ahrsd.calibration.field import CalStatus, FieldAttitude, FieldCalConfig, FieldCalibration, VehicleType
from ahrsd.core.angles import tilt_compensated_heading_rad
from ahrsd.calibration.models import Calibration, MagModel
from ahrsd.core.sample import make_sample
from support.field_data import HARD_IRON_UT, MAG_NOISE_UT, SITE, SOFT_DISTORTION, level_turns, tumble


def feed(session, traj, cal: Calibration | None = None, stop_when_done=True):
    for i in range(len(traj.t)):
        mag = traj.raw[i] if cal is None else cal.mag.apply(traj.raw[i])
        s = make_sample(traj.t[i], np.zeros(3), traj.accel[i], mag)
        est = FieldAttitude(roll_rad=traj.roll[i], pitch_rad=traj.pitch[i], yaw_rad=traj.yaw[i])
        session.add_sample(s, est)
        if stop_when_done and session.status.finished:
            return traj.t[i]
    return traj.t[-1]


def heading_rms_deg(model: MagModel, traj) -> float:
    """Tilt-compensated heading of the calibrated field against the truth: the trajectory's true heading
    (scipy, true-north NED) minus the site's declination, i.e. the magnetic heading."""
    cal = model.apply(traj.raw)
    psi = tilt_compensated_heading_rad(cal, traj.roll, traj.pitch)
    expected = traj.yaw - SITE.declination_rad
    err = (psi - expected + np.pi) % (2 * np.pi) - np.pi
    return float(np.degrees(np.sqrt(np.mean(err**2))))


def test_level_turns_complete_and_improve_heading():
    traj = level_turns()
    session = FieldCalibration(Calibration.identity(), FieldCalConfig(vehicle_type=VehicleType.LEVEL), SITE,
                               samples_are_calibrated=True)
    session.start()
    t_done = feed(session, traj, Calibration.identity())
    assert session.status == CalStatus.SUCCESS, session.fail_reason
    assert t_done < 120.0  # within two minutes of turning
    res = session.result
    before = heading_rms_deg(MagModel.identity(), traj)
    after = heading_rms_deg(res.model, traj)
    print(f"\nlevel turns: method {res.method}, fitness {res.fitness_mgauss:.1f} mG, done at {t_done:.0f} s; "
          f"heading RMS before {before:.2f} deg, after {after:.2f} deg")
    print(f"  hard iron fitted {np.round(res.model.hard_iron_ut, 2)} vs injected {HARD_IRON_UT}")
    assert after < before / 3
    # the full (vertical-channel) model: iron recovered, heading error below a degree
    assert res.method == "backstepping" and not res.partial
    assert np.linalg.norm(res.model.hard_iron_ut - HARD_IRON_UT) < 1.0
    assert np.allclose(res.model.soft_iron @ SOFT_DISTORTION, np.eye(3), atol=0.02)
    assert after < 1.0


def test_a_fit_that_cannot_run_fails_the_session_instead_of_fitting_offsets_only():
    """A broken import inside the full fit must show as a failed calibration, not as a "successful"
    offsets-only one that throws the soft-iron fit away unnoticed."""
    def broken_fit(method, data, reference, **options):
        raise ImportError(f"cannot import the {method} fit")

    session = FieldCalibration(Calibration.identity(), FieldCalConfig(vehicle_type=VehicleType.LEVEL), SITE,
                               samples_are_calibrated=False, fit_function=broken_fit)
    session.start()
    feed(session, level_turns())
    assert session.status == CalStatus.FAILED
    assert "cannot import the backstepping fit" in session.fail_reason


def test_tumble_without_position_uses_ellipsoid_and_recovers_iron():
    traj = tumble()
    session = FieldCalibration(Calibration.identity(), FieldCalConfig(vehicle_type=VehicleType.AUTO), None,
                               samples_are_calibrated=False)
    session.start()
    feed(session, traj)
    assert session.status == CalStatus.SUCCESS, session.fail_reason
    res = session.result
    assert res.method == "ellipsoid"
    print(f"\ntumble: fitness {res.fitness_mgauss:.2f} mG, sphere coverage {session.sphere_coverage:.2f}")
    assert np.allclose(res.model.hard_iron_ut, HARD_IRON_UT, atol=0.5)
    # without a reference: the soft iron up to a rotation (compare W·D's symmetric part) and a scale (the
    # field strength is unknown: the mean radius)
    from scipy.linalg import polar
    _, sym = polar(res.model.soft_iron @ SOFT_DISTORTION)
    assert np.allclose(sym / np.cbrt(np.linalg.det(sym)), np.eye(3), atol=0.01)
    assert session.sphere_coverage >= 0.75  # FieldCalConfig.sphere_target


def test_tumble_with_position_uses_the_vertical_channel_and_strong_hard_iron_still_completes():
    """A hand tumble with 3× the hard iron (the raw field's directions from the origin cover only part of the
    sphere): the completion mask follows the running sphere centre, and with the WMM reference the
    vertical-channel fit recovers the full soft iron, rotation included."""
    rng = np.random.default_rng(4)
    traj = tumble()
    raw = traj.true_body @ SOFT_DISTORTION.T + 3 * HARD_IRON_UT + rng.normal(0, MAG_NOISE_UT, traj.raw.shape)
    traj = SimpleNamespace(**{**traj.__dict__, "raw": raw})
    session = FieldCalibration(Calibration.identity(), FieldCalConfig(vehicle_type=VehicleType.AUTO), SITE,
                               samples_are_calibrated=False)
    session.start()
    t_done = feed(session, traj)
    assert session.status == CalStatus.SUCCESS, session.fail_reason
    res = session.result
    assert t_done < 90.0 and res.method == "backstepping"
    assert np.allclose(res.model.hard_iron_ut, 3 * HARD_IRON_UT, atol=0.5)
    assert np.allclose(res.model.soft_iron @ SOFT_DISTORTION, np.eye(3), atol=0.01)


def flat_turns_on_a_right_soft_iron(**stated):
    """±0.5° of tilt, the calibration in force with the right soft iron and the hard iron ~10 µT off (its
    metadata: `stated`); a field session run to its result. Returns (calibration in force, result, messages,
    trajectory)."""
    traj = level_turns(tilt_deg=0.5)
    current = Calibration.identity().with_sensor(
        "mag", MagModel(HARD_IRON_UT + np.array([6.0, -5.0, 4.0]), np.linalg.inv(SOFT_DISTORTION)), **stated)
    session = FieldCalibration(current, FieldCalConfig(vehicle_type=VehicleType.LEVEL), SITE,
                               samples_are_calibrated=False)
    session.start()
    feed(session, traj)
    return current, session.result, [text for _sev, text in session.pop_messages()], traj


def test_flat_turns_keep_a_good_soft_iron_and_fit_offsets_only_with_clear_message():
    """±0.5° of tilt, the soft iron in force already right, the hard iron off by ~10 µT: the full fit's own
    predicted heading error is larger than the change it would make, so only the offsets are refitted."""
    current, res, msgs, _traj = flat_turns_on_a_right_soft_iron()
    assert res is not None and res.status == CalStatus.SUCCESS
    cmp = res.quality["full_vs_offsets"]
    assert not cmp["use_full"] and cmp["full_heading_std_deg"] > cmp["offsets_heading_change_deg"]
    assert res.partial and res.method == "offsets"
    assert any("no better than the soft iron in force" in m and "fitted offsets only" in m for m in msgs), msgs
    assert any("offset undetermined: no usable GNSS course" in m for m in msgs), msgs
    # soft iron is kept from the calibration in force, never invented; the hard iron is corrected
    assert np.array_equal(res.model.soft_iron, current.mag.soft_iron)
    assert np.linalg.norm(res.model.hard_iron_ut - HARD_IRON_UT) < 1.0
    # the offsets are fitted on the attitude given, no levelling of its own: no frame tilt stated (ins: none)
    assert math.isnan(res.frame_tilt_std_deg) and math.isnan(res.frame_tilt_heading_std_deg)
    assert "frame_tilt_std_deg" not in res.proposed_calibration(current).metadata["mag"]


def test_flat_turns_with_strong_soft_iron_use_the_full_fit_and_name_what_is_undetermined():
    """The same ±0.5° turns with the identity in force (6 % scale, 3 % coupling): the full fit beats
    offsets-only by its own analysis; the report names the parameters the data leave undetermined."""
    session = FieldCalibration(Calibration.identity(), FieldCalConfig(vehicle_type=VehicleType.LEVEL), SITE,
                               samples_are_calibrated=False)
    session.start()
    traj = level_turns(tilt_deg=0.5)
    feed(session, traj)
    msgs = [text for _sev, text in session.pop_messages()]
    res = session.result
    assert res.method == "backstepping" and res.quality["full_vs_offsets"]["use_full"]
    assert "soft_iron[zz]" in res.undetermined
    assert any(m.startswith("Mag cal: undetermined:") and "soft_iron[zz]" in m for m in msgs), msgs
    assert heading_rms_deg(res.model, traj) < heading_rms_deg(MagModel.identity(), traj) / 5


def test_no_rotation_times_out_with_hint():
    traj = level_turns(duration_s=40.0, turn_period_s=1e9)  # sitting still
    session = FieldCalibration(Calibration.identity(), FieldCalConfig(timeout_s=30.0), SITE, samples_are_calibrated=False)
    session.start()
    feed(session, traj)
    assert session.status == CalStatus.FAILED
    assert "timed out" in session.fail_reason and "turn slowly through 360" in session.fail_reason


def test_retry_restarts_with_next_attempt():
    traj = level_turns(duration_s=40.0, turn_period_s=1e9)
    session = FieldCalibration(Calibration.identity(), FieldCalConfig(timeout_s=10.0, retry=True), SITE,
                               samples_are_calibrated=False)
    session.start()
    feed(session, traj, stop_when_done=False)
    assert session.attempt >= 3 and session.status.running


def test_delay_waits_in_sample_time_and_cancel_resets():
    traj = level_turns(duration_s=10.0)
    session = FieldCalibration(Calibration.identity(), FieldCalConfig(delay_s=5.0), SITE, samples_are_calibrated=False)
    session.start()
    for i in range(len(traj.t)):
        session.add_sample(make_sample(traj.t[i], np.zeros(3), traj.accel[i], traj.raw[i]),
                           FieldAttitude(roll_rad=0.0, pitch_rad=0.0, yaw_rad=traj.yaw[i]))
        if traj.t[i] < 4.9:
            assert session.status == CalStatus.WAITING_TO_START
    assert session.status == CalStatus.RUNNING_STEP_ONE and 0 < session.completion_pct < 50
    session.cancel()
    assert session.status == CalStatus.NOT_STARTED and session.completion_pct == 0


def test_no_samples_wallclock_timeout():
    session = FieldCalibration(Calibration.identity(), FieldCalConfig(no_sample_timeout_s=1.0), SITE)
    session.start()
    session.tick(100.0)
    session.tick(100.5)
    assert session.status.running
    session.tick(101.6)
    assert session.status == CalStatus.FAILED and "no magnetometer samples" in session.fail_reason


def test_calibrated_input_is_unwrapped_to_raw():
    """Feeding samples calibrated with the calibration in force gives the same result as feeding raw."""
    traj = level_turns(duration_s=100.0)
    current = Calibration.identity().with_sensor("mag", MagModel(np.array([5.0, 1.0, -2.0]), np.diag([1.02, 0.99, 1.0])))
    a = FieldCalibration(current, FieldCalConfig(vehicle_type=VehicleType.LEVEL), SITE, samples_are_calibrated=True)
    b = FieldCalibration(current, FieldCalConfig(vehicle_type=VehicleType.LEVEL), SITE, samples_are_calibrated=False)
    a.start()
    b.start()
    feed(a, traj, current)
    feed(b, traj, None)
    assert a.result is not None and b.result is not None
    assert np.allclose(a.result.model.hard_iron_ut, b.result.model.hard_iron_ut, atol=1e-6)
    # and both are the iron the data were made with (not merely the same answer twice)
    for res in (a.result, b.result):
        assert np.linalg.norm(res.model.hard_iron_ut - HARD_IRON_UT) < 1.0, res.model.hard_iron_ut


def test_an_offsets_only_refit_keeps_the_offset_of_a_calibration_that_stated_its_error():
    """The same flat turns, but the calibration in force states its predicted heading error (as a field session
    or `calibrate mag` records it). The refit keeps that calibration's soft iron, and with it its constant
    heading offset, so the result is no longer "undetermined": its offset is the in-force one, with the in-force
    figure, and the predicted heading error it then states covers the refitted heading's true error (scipy
    truth). Without a GNSS course this is what keeps a recalibrated vehicle's heading known (docs/daemon.md)."""
    from ahrsd.calibration.heading_trust import calibration_heading_sigma_rad

    current, res, msgs, traj = flat_turns_on_a_right_soft_iron(heading_std_deg=0.3, offset_std_deg=0.4)
    assert res is not None and res.status == CalStatus.SUCCESS and res.method == "offsets"
    assert res.offset_source == "calibration in force"
    assert abs(res.offset_std_deg - 0.5) < 1e-9                      # hypot(0.3, 0.4): the in-force figure
    assert any("offset +-0.5 deg (calibration in force)" in m for m in msgs), msgs
    sigma_deg = np.degrees(calibration_heading_sigma_rad(res.proposed_calibration(current)))
    assert np.isfinite(sigma_deg) and sigma_deg >= 0.5
    assert heading_rms_deg(res.model, traj) <= 3 * sigma_deg
