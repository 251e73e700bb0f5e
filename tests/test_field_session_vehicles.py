"""Field sessions on simulated level vehicles at ±2°, ±10° and ±30° of tilt with strong non-symmetric iron
(tests/support/field_vehicle.py), scored on attitudes the session never saw against the injected iron: the session
decides from the fit's observability analysis, gives what `ahrsd calibrate mag --method backstepping` gives
on the same samples, and with GNSS course over ground also removes the constant heading offset."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ahrsd.calibration.field import CalStatus, FieldAttitude, FieldCalConfig, FieldCalibration
from ahrsd.calibration.mag.offsets import fit_offsets_keep_soft_iron
from ahrsd.calibration.mag.fit_types import MagFitInput
from ahrsd.calibration.mag.fit import fit_mag
from ahrsd.calibration.heading_trust import calibration_heading_sigma_rad
from ahrsd.calibration.models import Calibration
from ahrsd.simulation.scenarios import LevelTurns

from support.field_vehicle import (SITE_FIELD, course_fixes, heading_errors_deg, heading_rms_deg, injected_iron, record,
                          samples, truth_euler, vehicle)


def run_session(block, config=None, courses=None, course_latency_s=0.1):
    """Feed the recording (and course fixes, each stamped with its time of validity) until the session has
    finished; returns (session, number of samples fed)."""
    eul = truth_euler(block)
    session = FieldCalibration(Calibration.identity(), config or FieldCalConfig(), SITE_FIELD)
    session.start()
    k = 0
    for i, s in enumerate(samples(block)):
        if courses is not None:
            arrival, _tv, course, speed = courses
            while k < arrival.size and arrival[k] <= s.t_s:
                session.add_course(arrival[k] - course_latency_s, course[k], speed[k])
                k += 1
        session.add_sample(s, FieldAttitude(roll_rad=eul[i, 2], pitch_rad=eul[i, 1], yaw_rad=eul[i, 0],
                                              rate_rad_s=block.truth_gyro_rad_s[i]))
        if session.status.finished:
            return session, i + 1
    return session, len(block.t_s)


@pytest.mark.parametrize("tilt_deg", [2.0, 10.0, 30.0])
def test_session_beats_offsets_only_and_matches_the_offline_fit(tilt_deg):
    block = record(vehicle(tilt_deg), 200.0)
    iron = injected_iron()
    session, n = run_session(block)
    res = session.result
    assert session.status == CalStatus.SUCCESS, session.fail_reason
    assert block.t_s[n - 1] < 120.0        # about 1.5 turns: a reasonable number of turns at any tilt
    assert res.method == "backstepping" and res.quality["full_vs_offsets"]["use_full"]
    offline = fit_mag("backstepping", MagFitInput(block.t_s[:n], block.mag_ut[:n], block.accel_m_s2[:n],
                                                  block.gyro_rad_s[:n]), SITE_FIELD)
    eul = truth_euler(block)[:n]
    offsets, _ = fit_offsets_keep_soft_iron(block.mag_ut[:n], np.eye(3), np.zeros(3), eul[:, 2], eul[:, 1],
                                            SITE_FIELD)
    field_rms = heading_rms_deg(res.model, iron, remove_mean=True)
    offline_rms = heading_rms_deg(offline.model, iron, remove_mean=True)
    offsets_rms = heading_rms_deg(offsets, iron, remove_mean=True)
    print(f"\n±{tilt_deg:.0f}°: done at {block.t_s[n - 1]:.0f} s; heading RMS (mean removed) field "
          f"{field_rms:.2f}°, offline {offline_rms:.2f}°, offsets-only {offsets_rms:.2f}°; with the offset "
          f"field {heading_rms_deg(res.model, iron):.2f}°; {res.accuracy_text()}")
    assert field_rms < offsets_rms / 3
    # the same within noise: 0.1° (the bound) or the fit's own predicted 1σ where that is larger
    # (at ±30° the waves move the field fast, and the 20 Hz session buffer and the full-rate recording
    # low-pass slightly differently)
    tolerance = max(0.1, res.heading_std_deg)
    assert abs(field_rms - offline_rms) < tolerance
    assert abs(heading_rms_deg(res.model, iron) - heading_rms_deg(offline.model, iron)) < tolerance
    if tilt_deg == 30.0:
        assert session._tilt_max_deg > 35.0     # beyond the old "being tumbled" threshold, still heading coverage


def test_gnss_course_removes_the_heading_offset_despite_a_current():
    """±2° of tilt (the offset is not observable from tilt), straight runs at 8 headings, a 0.18 m/s current,
    course noise 0.5°, latency 0.1 s: heading RMS on other attitudes including the offset ≤ 0.4°."""
    sc = vehicle(2.0, straight_runs=True)
    block = record(sc, 300.0)
    iron = injected_iron()
    courses = course_fixes(sc, 300.0, current_ne_m_s=(0.1, -0.15))
    session, n = run_session(block, courses=courses)
    res = session.result
    assert session.status == CalStatus.SUCCESS, session.fail_reason
    without, _ = run_session(block)
    total = heading_rms_deg(res.model, iron)
    print(f"\nGNSS course: offset {res.quality['gnss_course']['offset_deg']:.2f}° ± {res.offset_std_deg:.2f}°, "
          f"current {np.round(res.quality['gnss_course']['current_ne_m_s'], 3)} m/s (true [0.1, -0.15]); "
          f"heading RMS incl. offset {total:.2f}° (without GNSS {heading_rms_deg(without.result.model, iron):.2f}°)")
    assert res.offset_source == "GNSS course" and "GNSS course" in res.accuracy_text()
    # without the course the offset rests on the tilt alone (±2°: weakly, σ ~1.8°), stated and said so
    assert without.result.offset_source == "tilt" and math.isfinite(without.result.offset_std_deg)
    assert "a fixed-yaw command sets it better" in without.result.accuracy_text()
    assert total <= 0.4
    assert res.offset_std_deg < without.result.offset_std_deg / 3
    # the course measured the offset the field fit left (here −0.24° from tilt alone), and it was removed
    mean_without = float(np.mean(heading_errors_deg(without.result.model, iron)))
    mean_with = float(np.mean(heading_errors_deg(res.model, iron)))
    assert abs(mean_without + res.quality["gnss_course"]["offset_deg"]) < 0.1
    assert abs(mean_with) < 0.1
    assert np.allclose(res.quality["gnss_course"]["current_ne_m_s"], (0.1, -0.15), atol=0.05)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_tour_boats_offset_from_tilt_is_stated_covers_the_truth_and_is_not_called_undetermined(seed):
    """The README tour's `st2` walk: `ahrsd run --sim level-turns` (the scenario's own iron, wave tilt ≤ 7.5°), a
    session on an empty state directory, no GNSS. The back-stepping fit's offset 1σ (~0.5°, just above
    max_offset_std_deg) is the one the daemon uses after accepting (calibration/heading_trust.py: ACTIVE with a
    finite σ), so the report must state it, not call it undetermined (issue 28), and it must cover the offset
    the fit actually left, scored against the injected iron (the simulator's truth, not the fit)."""
    block = record(LevelTurns(), 200.0, seed=seed, iron="scenario")
    iron = injected_iron(seed, LevelTurns(), iron="scenario")
    session, _n = run_session(block)
    res = session.result
    assert session.status == CalStatus.SUCCESS, session.fail_reason
    text = res.accuracy_text()
    stored_sigma_deg = math.degrees(calibration_heading_sigma_rad(res.proposed_calibration(Calibration.identity())))
    errors = heading_errors_deg(res.model, iron)
    offset_deg = float(np.mean(errors))
    print(f"\nseed {seed}: {text}; true constant offset {offset_deg:+.3f}° (stated ±{res.offset_std_deg:.3f}°), "
          f"mean removed RMS {float(np.std(errors)):.3f}° (stated ±{res.heading_std_deg:.3f}°), stored {stored_sigma_deg:.3f}°")
    # the stated figures cover the truth
    assert abs(offset_deg) < 3 * res.offset_std_deg
    assert float(np.std(errors)) < 3 * res.heading_std_deg
    # what the report says and what the daemon uses agree: "undetermined" exactly when no heading figure is stored
    assert ("undetermined" in text) == math.isnan(stored_sigma_deg), text
    assert res.offset_source == "tilt" and f"offset +-{res.offset_std_deg:.1f} deg (tilt)" in text, text
    assert stored_sigma_deg == pytest.approx(math.hypot(res.heading_std_deg, res.offset_std_deg))


def test_a_back_stepping_session_states_its_levelling_tilt_as_calibrate_mag_does():
    """The session's back-stepping fit is levelled by the accelerometer, as `ahrsd calibrate mag --method
    backstepping` without --gnss: its predicted heading error holds the accelerometer bias's tilt, σ_b/g per axis,
    tan(dip)·σ_b/g in the heading (levelling_error.py). The calibration it proposes states both, as `calibrate mag`
    does (`frame_tilt_std_deg`, `frame_tilt_heading_std_deg`), so ins carries the tilt as its frame-tilt states and
    its harmonics leave that share out; the figures here are computed from the site's field and the bias σ the fit
    assumes (the chip's, without an accelerometer calibration), not read from the fit."""
    from ahrsd.calibration.heading_trust import (calibration_frame_tilt_heading_sigma_rad,
                                                 calibration_frame_tilt_sigma_rad)
    from ahrsd.estimator.accel_bias_prior import ACCEL_BIAS_SIGMA_UNCALIBRATED_M_S2
    from ahrsd.core.angles import STANDARD_GRAVITY_M_S2
    from ahrsd.daemon.service import Service
    from ahrsd.estimator.ins import Ins

    block = record(vehicle(10.0), 200.0)
    session, _n = run_session(block)
    res = session.result
    assert session.status == CalStatus.SUCCESS, session.fail_reason
    assert res.method == "backstepping" and res.quality["full_vs_offsets"]["use_full"]
    tilt_rad = ACCEL_BIAS_SIGMA_UNCALIBRATED_M_S2 / STANDARD_GRAVITY_M_S2
    share_rad = math.tan(SITE_FIELD.inclination_rad) * tilt_rad
    assert res.frame_tilt_std_deg == pytest.approx(math.degrees(tilt_rad), rel=1e-9)
    assert res.frame_tilt_heading_std_deg == pytest.approx(math.degrees(share_rad), rel=1e-6)
    assert res.frame_tilt_heading_std_deg <= res.heading_std_deg     # in it, in quadrature
    proposed = res.proposed_calibration(Calibration.identity())
    assert calibration_frame_tilt_sigma_rad(proposed) == pytest.approx(tilt_rad, rel=1e-9)
    assert calibration_frame_tilt_heading_sigma_rad(proposed) == pytest.approx(share_rad, rel=1e-6)
    ins = Ins(declination_rad=SITE_FIELD.declination_rad)
    Service._tell_calibration(ins, proposed)      # what the daemon does when it accepts the session's calibration
    assert ins.params.mag_calibration_frame_tilt_sigma_rad == pytest.approx(tilt_rad, rel=1e-9)
    assert ins.params.mag_calibration_frame_tilt_heading_sigma_rad == pytest.approx(share_rad, rel=1e-6)
