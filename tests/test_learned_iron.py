"""The learned iron (daemon.learned_iron) with the real `ins` in a started Service: it survives a restart, belongs
to its calibration and mounting, shows as read-only parameters, and the operator accepts it into the
calibration (checked against the field computed by hand) or resets it; both refused while armed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ahrsd.calibration.models import Calibration, MagModel
from ahrsd.calibration.store import CalibrationStore
from ahrsd.daemon.config import EndpointConfig, EstimatorConfig
from ahrsd.daemon.learned_iron import ACTION_ACCEPT, ACTION_RESET, CMD_LEARNED_IRON, FILE_NAME
from ahrsd.daemon.mavlink_io import mavlink
from service_rig import start_service_on, stop_service

OFFSET_UT = np.array([4.0, -6.5, 2.0])
COV_UT2 = np.diag([1.2, 0.8, 3.0]) + 0.1
SOFT = np.array([[1.05, 0.02, 0.0], [0.02, 0.97, 0.01], [0.0, 0.01, 1.01]])
HARD_UT = np.array([10.0, -3.0, 5.0])
LEARNED_SOFT = np.array([[1.04, -0.03, 0.01], [0.02, 0.95, 0.0], [-0.01, 0.02, 1.0]])   # I + D, body frame
LEARNED_SOFT_COV = np.diag(np.linspace(1e-4, 9e-4, 9))


def _calibration(hard_ut=HARD_UT):
    return Calibration.identity().with_sensor("mag", MagModel(np.asarray(hard_ut, float), SOFT), method="test",
                                              heading_std_deg=0.8, offset_std_deg=0.3)


def _start(state_dir):
    svc, loop = start_service_on((EndpointConfig("udpout:127.0.0.1:9"),), state_dir,
                                 estimator=EstimatorConfig("ins"))
    return svc, loop


def _said(svc) -> list[str]:
    """The texts the daemon sent to the ground station (daemon.outbound keeps the latest)."""
    return [text for _, text in svc.outbound.sent_texts]


def _command(action):
    return mavlink.MAVLink_command_long_message(1, 200, CMD_LEARNED_IRON, 0, float(action), 0, 0, 0, 0, 0, 0)


def test_the_learned_iron_survives_a_restart_and_is_shown_read_only(tmp_path):
    CalibrationStore(tmp_path).save(_calibration())
    svc, loop = _start(tmp_path)
    try:
        assert svc.pipeline.estimator.name == "ins"
        svc.pipeline.estimator.set_learned_iron(OFFSET_UT, COV_UT2)     # what ins learned in this run
        svc.learned_iron.tick(1e9)
        assert [svc.params.get(n) for n in ("MAG_LRN_X", "MAG_LRN_Y", "MAG_LRN_Z")] == pytest.approx(OFFSET_UT)
        assert svc.params.get("MAG_LRN_SD") == pytest.approx(math.sqrt(3.1))
        ok, reason = svc.params.set("MAG_LRN_X", 0.0)
        assert not ok and "read-only" in reason and svc.params.get("MAG_LRN_X") == pytest.approx(OFFSET_UT[0])
    finally:
        stop_service(svc, loop)                  # saves at stop
    assert (tmp_path / FILE_NAME).exists()
    svc, loop = _start(tmp_path)               # a new daemon, a new ins
    try:
        offset, cov = svc.pipeline.estimator.learned_iron()
        assert offset == pytest.approx(OFFSET_UT) and cov == pytest.approx(COV_UT2)
        assert svc.params.get("MAG_LRN_Y") == pytest.approx(OFFSET_UT[1])
    finally:
        stop_service(svc, loop)


def test_a_run_that_learned_nothing_is_not_announced_as_a_restored_iron(tmp_path, caplog):
    """A first run saves its still-zero iron at stop; the next start reads it back but has nothing learned to
    announce (it used to log "learned iron restored: [0.0, 0.0, 0.0] µT" at every start)."""
    CalibrationStore(tmp_path).save(_calibration())
    svc, loop = _start(tmp_path)
    stop_service(svc, loop)
    assert (tmp_path / FILE_NAME).exists()
    with caplog.at_level("INFO", logger="ahrsd.daemon.learned_iron"):
        svc, loop = _start(tmp_path)
        stop_service(svc, loop)
    assert svc.learned_iron.restored
    said = [r.getMessage() for r in caplog.records]
    assert not any("learned iron restored" in m for m in said), said
    assert any("nothing learned yet" in m for m in said), said


def test_the_learned_soft_iron_survives_a_restart_too(tmp_path):
    CalibrationStore(tmp_path).save(_calibration())
    svc, loop = _start(tmp_path)
    try:
        svc.pipeline.estimator.set_learned_iron(OFFSET_UT, COV_UT2, LEARNED_SOFT, LEARNED_SOFT_COV)
    finally:
        stop_service(svc, loop)
    svc, loop = _start(tmp_path)
    try:
        soft, soft_cov = svc.pipeline.estimator.learned_soft_iron()
        assert soft == pytest.approx(LEARNED_SOFT) and soft_cov == pytest.approx(LEARNED_SOFT_COV)
        assert svc.pipeline.estimator.learned_iron()[0] == pytest.approx(OFFSET_UT)
        # the operator sees it: MAG_LRN_S<row><column> = I + D, MAG_LRN_SSD its largest 1σ (read-only)
        svc.learned_iron.tick(1e9)
        shown = [[svc.params.get(f"MAG_LRN_S{r}{c}") for c in (1, 2, 3)] for r in (1, 2, 3)]
        assert shown == pytest.approx(LEARNED_SOFT, abs=1e-6)
        assert svc.params.get("MAG_LRN_SSD") == pytest.approx(math.sqrt(9e-4), rel=1e-5)
        ok, reason = svc.params.set("MAG_LRN_S12", 0.0)
        assert not ok and "read-only" in reason
    finally:
        stop_service(svc, loop)


def test_a_learned_iron_of_another_calibration_is_discarded_and_a_new_calibration_resets_it(tmp_path):
    CalibrationStore(tmp_path).save(_calibration())
    svc, loop = _start(tmp_path)
    try:
        svc.pipeline.estimator.set_learned_iron(OFFSET_UT, COV_UT2)
    finally:
        stop_service(svc, loop)
    CalibrationStore(tmp_path).save(_calibration(HARD_UT + 1.0))      # recalibrated while the daemon was off
    svc, loop = _start(tmp_path)
    try:
        assert not np.any(svc.pipeline.estimator.learned_iron()[0])
        svc.pipeline.estimator.set_learned_iron(OFFSET_UT, COV_UT2)
        svc.apply_calibration(_calibration(HARD_UT - 1.0), reason="test")   # a new calibration accepted
        assert not np.any(svc.pipeline.estimator.learned_iron()[0])
        svc.pipeline.estimator.set_learned_iron(OFFSET_UT, COV_UT2)
        gyro_only = svc.pipeline.calibration.with_sensor("gyro", svc.pipeline.calibration.gyro, method="x")
        svc.apply_calibration(gyro_only, reason="test")                    # the magnetometer model unchanged
        assert svc.pipeline.estimator.learned_iron()[0] == pytest.approx(OFFSET_UT)
        svc.params.set("MNT_YAW_DEG", 90.0)                                 # the body frame moved
        assert not np.any(svc.pipeline.estimator.learned_iron()[0])
    finally:
        stop_service(svc, loop)


def test_accept_folds_the_learned_iron_into_the_hard_iron_and_resets_it(tmp_path):
    CalibrationStore(tmp_path).save(_calibration())
    svc, loop = _start(tmp_path)
    try:
        svc.params.set("MNT_YAW_DEG", 30.0)           # a mounting, so the body → sensor rotation matters
        svc.pipeline.estimator.set_learned_iron(OFFSET_UT, COV_UT2, LEARNED_SOFT, LEARNED_SOFT_COV)
        c = svc.pipeline.mounting
        raw = np.array([[25.0, -4.0, 40.0], [-12.0, 18.0, 35.0], [3.0, 3.0, -20.0]])
        # what ins used: the body field of the old calibration less the learned hard iron, through the inverse of
        # the learned soft iron (by hand)
        used = np.array([np.linalg.inv(LEARNED_SOFT) @ (c @ (SOFT @ (r - HARD_UT)) - OFFSET_UT) for r in raw])
        assert svc.learned_iron.handle_command(_command(ACTION_ACCEPT)) == mavlink.MAV_RESULT_ACCEPTED
        new = svc.pipeline.calibration.mag
        assert np.array([c @ new.apply(r) for r in raw]) == pytest.approx(used, abs=1e-9)
        assert not np.allclose(new.soft_iron, SOFT)
        assert svc.pipeline.estimator.learned_soft_iron()[0] == pytest.approx(np.eye(3))
        assert CalibrationStore(tmp_path).load().mag.hard_iron_ut == pytest.approx(new.hard_iron_ut)
        assert not np.any(svc.pipeline.estimator.learned_iron()[0])
        assert any("Learned iron accepted" in t for t in _said(svc))
        meta = svc.pipeline.calibration.metadata["mag"]
        assert meta["method"] == "learned-iron" and meta["learned_iron_ut"] == pytest.approx(OFFSET_UT)
        from ahrsd.calibration.heading_trust import calibration_heading_sigma_rad    # still a figure ins can use
        assert math.degrees(calibration_heading_sigma_rad(svc.pipeline.calibration)) >= math.hypot(0.8, 0.3)
        # nothing left to accept
        assert svc.learned_iron.handle_command(_command(ACTION_ACCEPT)) == mavlink.MAV_RESULT_FAILED
    finally:
        stop_service(svc, loop)


def test_a_refused_mag_lrn_act_write_says_why_once_and_an_accept_names_the_iron_in_numbers(tmp_path):
    """A ground station's MAG_LRN_ACT write the daemon refuses (nothing learned yet; armed) is said in one
    STATUSTEXT, the parameter refusal's (walk27: the part's text and then the refusal's, the reason twice); a done
    accept says the iron it folded in as `magcal status` shows one ("+23.3 -29.7 +19.8 uT", not "+[23.3, …]")."""
    from support.kept_link import KeptLink
    from support.mavlink_feed import as_if_from

    def write(value):
        msg = mavlink.MAVLink_param_set_message(1, 200, b"MAG_LRN_ACT", value, mavlink.MAV_PARAM_TYPE_REAL32)
        svc.param_protocol.on_message(KeptLink(), as_if_from(msg, 255, 190), "PARAM_SET", broadcast=False)

    CalibrationStore(tmp_path).save(_calibration())
    svc, loop = _start(tmp_path)
    try:
        svc.outbound.sent_texts.clear()
        write(1.0)                                   # nothing learned yet
        assert [t for t in _said(svc) if "nothing learned yet" in t] == [
            "ahrsd: MAG_LRN_ACT 1: Learned iron: nothing learned yet"], _said(svc)
        svc.pipeline.estimator.set_learned_iron(OFFSET_UT, COV_UT2)
        svc.autopilot.armed = True
        svc.outbound.sent_texts.clear()
        write(1.0)
        assert [t for t in _said(svc) if "Disarm" in t] == ["ahrsd: MAG_LRN_ACT 1: Disarm to change the learned iron"]
        svc.autopilot.armed = False
        svc.outbound.sent_texts.clear()
        write(1.0)
        assert _said(svc).count("Learned iron accepted into the calibration: hard iron +4.0 -6.5 +2.0 uT") == 1, \
            _said(svc)                               # OFFSET_UT, written out
    finally:
        stop_service(svc, loop)


def test_reset_forgets_it_and_both_commands_are_refused_while_armed(tmp_path):
    CalibrationStore(tmp_path).save(_calibration())
    svc, loop = _start(tmp_path)
    try:
        ins = svc.pipeline.estimator
        ins.set_learned_iron(OFFSET_UT, COV_UT2)
        before = svc.pipeline.calibration
        svc.autopilot.armed = True
        for action in (ACTION_ACCEPT, ACTION_RESET):
            assert svc.learned_iron.handle_command(_command(action)) == mavlink.MAV_RESULT_TEMPORARILY_REJECTED
        assert ins.learned_iron()[0] == pytest.approx(OFFSET_UT) and svc.pipeline.calibration is before
        assert "Disarm to change the learned iron" in _said(svc)
        svc.autopilot.armed = False
        assert svc.learned_iron.handle_command(_command(ACTION_RESET)) == mavlink.MAV_RESULT_ACCEPTED
        assert not np.any(ins.learned_iron()[0]) and svc.pipeline.calibration is before
        assert svc.learned_iron.handle_command(_command(7)) != mavlink.MAV_RESULT_ACCEPTED
        # the same from a ground station's parameter list: MAG_LRN_ACT (momentary)
        ins.set_learned_iron(OFFSET_UT, COV_UT2)
        svc.autopilot.armed = True
        ok, reason = svc.params.set("MAG_LRN_ACT", 2.0)
        assert not ok and "Disarm" in reason and ins.learned_iron()[0] == pytest.approx(OFFSET_UT)
        svc.autopilot.armed = False
        ok, _ = svc.params.set("MAG_LRN_ACT", 2.0)
        assert ok and not np.any(ins.learned_iron()[0]) and svc.params.get("MAG_LRN_ACT") == 0.0
    finally:
        stop_service(svc, loop)
    svc, loop = _start(tmp_path)                  # the reset persisted too
    try:
        assert not np.any(svc.pipeline.estimator.learned_iron()[0])
    finally:
        stop_service(svc, loop)


def _aided_ins(**params):
    """A real ins that knows its position (a fix after a second at rest), so it can say the heading σ its learned
    iron leaves."""
    from ahrsd.core.gnss import make_fix
    from ahrsd.core.sample import make_sample
    from ahrsd.estimator.ins import Ins

    ins = Ins(**params)
    acc, mag = np.array([0.0, 0.0, -9.81]), np.array([18.0, 0.0, 45.0])
    for i in range(120):
        ins.update(make_sample(0.01 * i, np.zeros(3), acc, mag))
        if i == 100:
            ins.update_gnss(make_fix(0.5, 52.0, 4.0, 10.0, np.zeros(3)))
    return ins


def test_the_part_alone_knows_a_learning_estimator_by_its_declared_interface(tmp_path):
    """LearnedIron built alone on a real Pipeline: with ins (an IronLearningEstimator) the accepted calibration's
    heading σ is the old one and the estimator's own σ for its learned iron in quadrature, worked out here;
    with the thesis filter (which learns none) the part shows −1 and refuses; mekf (which learns in turns) does
    not take up the file ins wrote (another source: dropped and counted) and does not overwrite it. (Broken by renaming
    learned_iron_heading_sigma_rad in the Protocol: ins is no longer recognised, 6 of 7 tests here fail; by
    ignoring the estimator's σ for the hard iron's diagonal: 3.73° instead of 4.84°.)"""
    from ahrsd.calibration.heading_trust import calibration_heading_sigma_rad
    from ahrsd.daemon.learned_iron import LearnedIron
    from ahrsd.daemon.pipeline import Pipeline
    from ahrsd.estimator.base import IronLearningEstimator
    from ahrsd.estimator.mekf import Mekf

    ins = _aided_ins()
    from ahrsd.estimator.thesis_kf import ThesisKf

    assert isinstance(ins, IronLearningEstimator) and isinstance(Mekf(), IronLearningEstimator)
    assert not isinstance(ThesisKf(), IronLearningEstimator)
    ins.set_learned_iron(OFFSET_UT, COV_UT2, LEARNED_SOFT, LEARNED_SOFT_COV)
    iron_sigma = ins.learned_iron_heading_sigma_rad()
    assert math.isfinite(iron_sigma)
    horizontal_ut = 18.0
    assert abs(iron_sigma - math.sqrt(max(COV_UT2[0, 0], COV_UT2[1, 1])) / horizontal_ut) > 1e-3   # tells them apart
    pipeline = Pipeline(ins, _calibration())
    shown, texts = {}, []

    def apply_calibration(cal):
        pipeline.calibration = cal

    part = LearnedIron(tmp_path, pipeline, publish=shown.__setitem__, statustext=lambda sev, t: texts.append(t),
                       armed=lambda: False, apply_calibration=apply_calibration,
                       horizontal_field_ut=lambda: horizontal_ut)
    part.restore()
    assert shown["MAG_LRN_X"] == pytest.approx(OFFSET_UT[0])
    old_sigma = calibration_heading_sigma_rad(pipeline.calibration)
    assert part.act(ACTION_ACCEPT)[0] == mavlink.MAV_RESULT_ACCEPTED, texts
    assert pipeline.calibration.metadata["mag"]["heading_std_deg"] == pytest.approx(
        math.degrees(math.hypot(old_sigma, iron_sigma)), rel=1e-12)

    assert shown["MAG_LRN_SRC"] == 0.0                     # ins reset its iron when it was accepted
    pipeline.estimator = Mekf()
    before = (tmp_path / FILE_NAME).read_bytes()              # ins's, on the calibration now in force
    mekf_part = LearnedIron(tmp_path, pipeline, publish=shown.__setitem__, statustext=lambda sev, t: None,
                            armed=lambda: False, apply_calibration=apply_calibration)
    assert mekf_part.restore() is False and mekf_part.rejections == 1
    mekf_part.tick(0.0)
    mekf_part.save_now()
    assert (tmp_path / FILE_NAME).read_bytes() == before and shown["MAG_LRN_SD"] == 0.0
    assert mekf_part.act(ACTION_ACCEPT)[0] == mavlink.MAV_RESULT_FAILED      # nothing learned yet
    pipeline.estimator = ThesisKf()
    none_part = LearnedIron(tmp_path / "m", pipeline, publish=shown.__setitem__, statustext=lambda sev, t: None,
                            armed=lambda: False, apply_calibration=apply_calibration)
    assert none_part.restore() is False and shown["MAG_LRN_SD"] == -1.0
    assert none_part.act(ACTION_ACCEPT)[0] == mavlink.MAV_RESULT_UNSUPPORTED


class _FakeConn:
    """Answers PARAM_REQUEST_READ with PARAM_VALUE from `values`, as the daemon (1, 200) would."""

    def __init__(self, values):
        from types import SimpleNamespace

        self.values, self.queue = values, []
        self.mav = SimpleNamespace(param_request_read_send=self._read)
        self._wire = mavlink.MAVLink(None, srcSystem=1, srcComponent=200)

    def _read(self, sys_id, comp_id, name, index):
        from ahrsd.daemon.messages import param_value

        name = name.decode()
        if name in self.values:
            msg = param_value(name, self.values[name], 0, 1)
            self.queue.append(mavlink.MAVLink(None).parse_char(bytearray(msg.pack(self._wire))))

    def recv_match(self, **kw):
        return self.queue.pop(0) if self.queue else None


def test_magcal_status_shows_the_learned_iron_and_the_cli_has_its_actions():
    import io

    from ahrsd.cli.magcal_client import MagCalClient
    from ahrsd.cli.main import build_parser

    soft = {f"MAG_LRN_S{r + 1}{c + 1}": float(LEARNED_SOFT[r, c]) for r in range(3) for c in range(3)}
    client = MagCalClient(_FakeConn({"MAG_LRN_X": 4.0, "MAG_LRN_Y": -6.5, "MAG_LRN_Z": 2.0, "MAG_LRN_SD": 1.76,
                                     **soft, "MAG_LRN_SSD": 0.03}), timeout_s=0.5, out=io.StringIO())
    client.sys, client.comp = 1, 200
    text = client.learned_iron_text()
    assert "+4.00 -6.50 +2.00 uT" in text and "1.76 uT" in text and "accept-learned" in text
    # the soft iron, row by row (LEARNED_SOFT written out by hand), and its σ
    assert "[+1.0400 -0.0300 +0.0100] [+0.0200 +0.9500 +0.0000] [-0.0100 +0.0200 +1.0000]" in text
    assert "1-sigma up to 0.0300" in text
    none = {n: 0.0 for n in ("MAG_LRN_X", "MAG_LRN_Y", "MAG_LRN_Z", *soft)} | {"MAG_LRN_SD": -1.0, "MAG_LRN_SSD": -1.0}
    client = MagCalClient(_FakeConn(none), timeout_s=0.5, out=io.StringIO())
    client.sys, client.comp = 1, 200
    assert "learns none" in client.learned_iron_text()
    # what learned it (MAG_LRN_SRC): mekf's correction learned in turns, shown as the GNSS one is, with its source
    turns = {n: 0.0 for n in none} | {"MAG_LRN_X": 5.2, "MAG_LRN_Y": 3.0, "MAG_LRN_SD": 0.28, "MAG_LRN_SSD": -1.0,
                                      "MAG_LRN_S11": 1.0, "MAG_LRN_S22": 1.0, "MAG_LRN_S33": 1.0, "MAG_LRN_SRC": 2.0}
    client = MagCalClient(_FakeConn(turns), timeout_s=0.5, out=io.StringIO())
    client.sys, client.comp = 1, 200
    text = client.learned_iron_text()
    assert "hard +5.20 +3.00 +0.00 uT, 1-sigma up to 0.28 uT (source: turns, no GNSS)" in text, text
    assert "none learned" in text
    # nothing learned yet (MAG_LRN_SRC 0, what the daemon publishes until the estimator learned something): said so,
    # with no zero "hard iron" and no hint to accept what the daemon would refuse ("nothing learned yet", FAILED)
    nothing = {n: 0.0 for n in none} | {"MAG_LRN_SD": 0.0, "MAG_LRN_SSD": -1.0, "MAG_LRN_S11": 1.0,
                                        "MAG_LRN_S22": 1.0, "MAG_LRN_S33": 1.0, "MAG_LRN_SRC": 0.0}
    client = MagCalClient(_FakeConn(nothing), timeout_s=0.5, out=io.StringIO())
    client.sys, client.comp = 1, 200
    text = client.learned_iron_text()
    assert text.startswith("learned iron: nothing learned yet"), text
    assert "accept-learned" not in text and "hard +" not in text, text
    for action in ("accept-learned", "reset-learned"):
        assert build_parser().parse_args(["magcal", action]).action == action


def test_without_a_heading_figure_the_accepted_calibration_takes_the_estimators_unmodelled_iron_as_its_floor(tmp_path):
    """The calibration in force states no heading error (a fit without one): the accepted one's heading σ is what
    the estimator says its learned iron leaves unexplained, over the horizontal field, in quadrature with the
    learned iron's own σ. ins built with 2.5 µT unexplained (not its 1 µT default), horizontal field 18 µT:
    worked here as hypot(2.5/18, σ_iron)."""
    from ahrsd.calibration.heading_trust import calibration_heading_sigma_rad
    from ahrsd.daemon.learned_iron import LearnedIron
    from ahrsd.daemon.pipeline import Pipeline

    unexplained_ut, horizontal_ut = 2.5, 18.0
    ins = _aided_ins(iron_unmodelled_ut=unexplained_ut)
    ins.set_learned_iron(OFFSET_UT, COV_UT2, LEARNED_SOFT, LEARNED_SOFT_COV)
    iron_sigma = ins.learned_iron_heading_sigma_rad()
    assert math.isfinite(iron_sigma)
    no_figure = Calibration.identity().with_sensor("mag", MagModel(HARD_UT, SOFT), method="test")
    assert math.isnan(calibration_heading_sigma_rad(no_figure))
    pipeline = Pipeline(ins, no_figure)

    def apply_calibration(cal):
        pipeline.calibration = cal

    part = LearnedIron(tmp_path, pipeline, publish=lambda name, value: None, statustext=lambda sev, t: None,
                       armed=lambda: False, apply_calibration=apply_calibration,
                       horizontal_field_ut=lambda: horizontal_ut)
    assert part.act(ACTION_ACCEPT)[0] == mavlink.MAV_RESULT_ACCEPTED
    assert pipeline.calibration.metadata["mag"]["heading_std_deg"] == pytest.approx(
        math.degrees(math.hypot(unexplained_ut / horizontal_ut, iron_sigma)), rel=1e-12)
