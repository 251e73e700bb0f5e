"""The hard iron mekf learned in turns without GNSS survives a restart (issue 28 item 2; daemon/learned_iron.py,
the same store and rules as ins's GNSS-learned iron; estimator/field_circle_correction.py `restore`).

The vehicle and its truth are test_field_circle's (tests/support/turning_in_place.py): a level vehicle turning in
place at 4 °/s whose calibration leaves a hard iron of (5.2, 3.0) µT in the field (6 µT against H = 20 µT: up to
±17.5° of heading) while it claims 0.5°; the heading error is against scipy's truth, never the code under test. Run
1 learns the correction and the store saves it; run 2 (a new filter, another noise seed) starts with it applied: its
heading is right from the start, and its σ claims no more than run 1 knew (σ_c over H, H from the simulator's
field). A changed calibration drops the saved correction, as does a corrupt file: each a counted rejection.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from ahrsd.calibration.models import Calibration, MagModel
from ahrsd.daemon.learned_iron import ACTION_ACCEPT, ACTION_RESET, FILE_NAME, LearnedIron
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.pipeline import Pipeline
from ahrsd.estimator.base import LEARNED_IN_TURNS
from ahrsd.estimator.mekf import Mekf
from support.turning_in_place import CLAIMED_SIGMA_RAD, H_UT, run_turning

IRON_UT = (5.2, 3.0)
SOFT = np.array([[1.05, 0.02, 0.0], [0.02, 0.97, 0.01], [0.0, 0.01, 1.01]])
START_S = 30.0              # run 2's start: before its own circle could judge anything (270° at 4 °/s = 67.5 s)


def _calibration(hard_ut=(10.0, -3.0, 5.0)):
    return Calibration.identity().with_sensor("mag", MagModel(np.asarray(hard_ut, float), SOFT), method="test",
                                              heading_std_deg=0.5, offset_std_deg=0.3)


def _store(state_dir, estimator, calibration, texts=None):
    pipeline = Pipeline(estimator, calibration)

    def apply_calibration(cal):
        pipeline.calibration = cal

    shown: dict[str, float] = {}
    part = LearnedIron(state_dir, pipeline, publish=shown.__setitem__,
                       statustext=lambda sev, text: (texts if texts is not None else []).append(text),
                       armed=lambda: False, apply_calibration=apply_calibration)
    return part, shown, pipeline


def _new_mekf():
    return Mekf(mag_calibration_sigma_rad=CLAIMED_SIGMA_RAD)


@pytest.fixture(scope="module")
def learned(tmp_path_factory):
    """Run 1: 200 s of turns; the store saves what mekf learned. (state_dir, the saved document, run 1's filter)"""
    state_dir = tmp_path_factory.mktemp("state")
    _, _, _, _, f = run_turning(lambda **kw: _new_mekf(), IRON_UT, seconds=200.0)
    part, shown, _ = _store(state_dir, f, _calibration())
    assert part.restore() is False                   # nothing saved yet
    part.save_now()
    return state_dir, json.loads((state_dir / FILE_NAME).read_text()), f, shown


def test_run_one_saves_what_it_learned_in_turns(learned):
    state_dir, doc, f, shown = learned
    assert doc["source"] == LEARNED_IN_TURNS
    assert np.allclose(doc["offset_ut"][:2], IRON_UT, atol=0.5) and doc["offset_ut"][2] == 0.0
    sigma_ut = math.sqrt(doc["cov_ut2"][0][0])
    assert 0.0 < sigma_ut < 0.5
    # shown as the GNSS one is, with its source: 2 = turns, no GNSS
    assert shown["MAG_LRN_X"] == pytest.approx(doc["offset_ut"][0]) and shown["MAG_LRN_SRC"] == 2.0
    assert shown["MAG_LRN_SSD"] == -1.0                      # no soft iron is learned in turns


def _run_two(state_dir, calibration, seed=5):
    f = _new_mekf()
    part, shown, _ = _store(state_dir, f, calibration)
    restored = part.restore()
    t, err, sig, _, _ = run_turning(lambda **kw: f, IRON_UT, seconds=START_S, seed=seed)
    return restored, part, t, err, sig, f


def test_run_two_starts_with_it_applied_and_sigma_claims_no_more_than_run_one_knew(learned):
    state_dir, doc, _, _ = learned
    restored, part, t, err, sig, f = _run_two(state_dir, _calibration())
    assert restored and part.rejections == 0
    ok = np.isfinite(err)
    # heading right from the start against the truth (without it: the iron's sinusoid, up to 17.5°)
    after_init = ok & (t >= 1.0)   # for σ: the first second is the filter's own start
    assert math.degrees(np.max(np.abs(err[ok]))) <= 2.0     # from the first estimate (its field corrected too)
    _, _, t0, err0, _, _ = _run_two(state_dir / "empty", _calibration())
    assert math.degrees(np.max(np.abs(err0[np.isfinite(err0) & (t0 >= 1.0)]))) >= 5.0
    # σ honest, and no smaller than what run 1 knew of the correction: its σ_c (µT) over the simulator's H
    assert np.all(np.abs(err[ok]) <= 3.0 * sig[ok])
    known_rad = math.sqrt(doc["cov_ut2"][0][0]) / H_UT
    assert f.learned_iron_heading_sigma_rad() >= known_rad and np.all(sig[after_init] >= known_rad)


def test_a_changed_calibration_drops_it_as_a_counted_rejection(learned, tmp_path):
    state_dir, doc, _, _ = learned
    (tmp_path / FILE_NAME).write_text(json.dumps(doc))
    restored, part, t, err, sig, f = _run_two(tmp_path, _calibration(hard_ut=(10.5, -3.0, 5.0)))
    assert not restored and part.rejections == 1
    assert not np.any(f.learned_iron()[0])
    assert json.loads((tmp_path / FILE_NAME).read_text())["calibration_key"] == part.key   # now tied to the new one


def test_with_the_learning_switched_off_it_is_not_applied(learned, tmp_path):
    state_dir, doc, _, _ = learned
    (tmp_path / FILE_NAME).write_text(json.dumps(doc))
    f = Mekf(mag_calibration_sigma_rad=CLAIMED_SIGMA_RAD, mag_field_circle_correction=False)
    part, _, _ = _store(tmp_path, f, _calibration())
    assert part.restore() is False and part.rejections == 1 and not np.any(f.learned_iron()[0])


def test_a_saved_correction_with_a_vertical_part_is_a_counted_rejection(learned, tmp_path):
    """The turns learn no vertical iron (a level circle's centre is horizontal): a file claiming one was not
    written by them, so none of it is applied (FieldCircleCorrection.restore refuses it)."""
    state_dir, doc, _, _ = learned
    (tmp_path / FILE_NAME).write_text(json.dumps({**doc, "offset_ut": [*doc["offset_ut"][:2], 1.0]}))
    f = _new_mekf()
    part, _, _ = _store(tmp_path, f, _calibration())
    assert part.restore() is False and part.rejections == 1 and not np.any(f.learned_iron()[0])


@pytest.mark.parametrize("text", ["{not json", json.dumps({"format": "something else"})])
def test_a_corrupt_file_is_a_counted_rejection(tmp_path, text):
    (tmp_path / FILE_NAME).write_text(text)
    part, shown, _ = _store(tmp_path, _new_mekf(), _calibration())
    assert part.restore() is False and part.rejections == 1 and shown["MAG_LRN_SRC"] == 0.0


def test_accept_folds_it_into_the_calibration_and_reset_forgets_it(learned, tmp_path):
    state_dir, doc, _, _ = learned
    for action in (ACTION_ACCEPT, ACTION_RESET):
        (tmp_path / FILE_NAME).write_text(json.dumps(doc))
        f = _new_mekf()
        texts: list[str] = []
        part, shown, pipeline = _store(tmp_path, f, _calibration(), texts)
        assert part.restore()
        assert part.act(action)[0] == mavlink.MAV_RESULT_ACCEPTED, texts
        assert not np.any(f.learned_iron()[0]) and shown["MAG_LRN_SRC"] == 0.0
        if action == ACTION_ACCEPT:
            # h' = h + W⁻¹·b (no mounting): worked with numpy's solve of the calibration's own W
            want = np.array([10.0, -3.0, 5.0]) + np.linalg.solve(SOFT, np.asarray(doc["offset_ut"]))
            assert np.allclose(pipeline.calibration.mag.hard_iron_ut, want, atol=1e-9)
        else:
            assert pipeline.calibration.mag.hard_iron_ut.tolist() == [10.0, -3.0, 5.0]
            assert not np.any(json.loads((tmp_path / FILE_NAME).read_text())["offset_ut"])


def test_a_filter_reset_or_another_sensors_calibration_keeps_it_a_new_magnetometer_calibration_drops_it(learned,
                                                                                                       tmp_path):
    """The correction belongs to the magnetometer calibration, not to the filter: the pipeline's reset (after a
    rejected sample) and the daemon's calibration path for a gyro calibration (set_mag_calibration_sigma, then
    relearn_field_reference) keep it (else the next periodic save would write nothing over it); the store resets
    it when another magnetometer calibration comes into force."""
    state_dir, doc, _, _ = learned
    (tmp_path / FILE_NAME).write_text(json.dumps(doc))
    f = _new_mekf()
    part, _, pipeline = _store(tmp_path, f, _calibration())
    assert part.restore()
    for keeps in (f.reset, lambda: f.set_mag_calibration_sigma(CLAIMED_SIGMA_RAD), f.relearn_field_reference):
        keeps()
        assert np.array_equal(f.learned_iron()[0], doc["offset_ut"])
        assert np.array_equal(f.learned_iron()[1], np.asarray(doc["cov_ut2"]))
    pipeline.calibration = _calibration(hard_ut=(10.5, -3.0, 5.0))
    part.calibration_changed()
    assert not np.any(f.learned_iron()[0])


def test_forgetting_the_correction_widens_sigma_by_the_heading_error_it_removed():
    """The operator's reset (or the correction folded into the calibration) puts the field back as the calibration
    gives it: until the circle judges it again, the published yaw σ must cover the sinusoid a hard iron of the
    removed size leaves, amplitude asin(|b|/H) (RMS amplitude/√2), worked here from the simulated iron and field."""
    from support.turning_in_place import FIELD_NED, G, RATE_HZ, VEHICLE_TURN_RATE_RAD_S
    from scipy.spatial.transform import Rotation

    from ahrsd.core.sample import make_sample

    t, _, sig, _, f = run_turning(lambda **kw: _new_mekf(), IRON_UT, seconds=200.0)
    assert sig[-1] < math.radians(3.0)                       # learned: σ small again before the reset
    f.reset_learned_iron()
    t_s = t[-1] + 1.0 / RATE_HZ
    heading = 0.3 + VEHICLE_TURN_RATE_RAD_S * t_s
    mag = Rotation.from_euler("ZYX", [heading, 0.0, 0.0]).inv().apply(FIELD_NED) + np.array([*IRON_UT, 0.0])
    out = f.update(make_sample(t_s, np.array([0.0, 0.0, VEHICLE_TURN_RATE_RAD_S]), np.array([0.0, 0.0, -G]), mag))
    removed_rms_rad = math.asin(math.hypot(*IRON_UT) / H_UT) / math.sqrt(2.0)
    assert out.sigma_rpy_rad[2] >= 0.9 * removed_rms_rad, (math.degrees(out.sigma_rpy_rad[2]),
                                                          math.degrees(removed_rms_rad))
