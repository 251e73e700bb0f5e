"""The ArduPilot source-set re-alignment sequence (daemon.source_set_realign) on its own: the order of the
commands, the retries of the switch back, and what the operator is told when the autopilot never confirms."""

from __future__ import annotations

import math

import pytest

from ahrsd.daemon.config import ConfigError, OutputsConfig
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.source_set_check import AXES, MAX_REQUESTS, SourceSetCheck
from ahrsd.daemon.source_set_realign import ACK_TIMEOUT_S, SWITCH_BACK_S, SourceSetRealign


def ack(result, command=42007):
    return mavlink.MAVLink_command_ack_message(command, result, 0, 0, 1, 200)


def make(alternate=2):
    sent, warnings = [], []
    return SourceSetRealign(alternate, sent.append, warnings.append), sent, warnings


def test_switches_away_publishes_then_switches_back_after_the_delay():
    r, sent, _ = make(3)
    r.start(10.0)
    assert sent == [3] and not r.publish_new_heading
    r.on_command_ack(ack(mavlink.MAV_RESULT_ACCEPTED, command=400))      # another command's answer: not ours
    r.tick(10.1)
    assert not r.publish_new_heading
    r.on_command_ack(ack(mavlink.MAV_RESULT_ACCEPTED))
    r.tick(10.2)
    assert r.publish_new_heading and sent == [3]
    r.tick(10.2 + SWITCH_BACK_S - 0.01)
    assert sent == [3]                                   # not before the fusion horizon has the new heading
    r.tick(10.2 + SWITCH_BACK_S)
    assert sent == [3, 1]
    r.on_command_ack(ack(mavlink.MAV_RESULT_ACCEPTED))
    r.tick(10.8)
    assert r.state == r.DONE and not r.gave_up


@pytest.mark.parametrize("answer", [mavlink.MAV_RESULT_DENIED, None])
def test_a_refused_or_unanswered_first_switch_gives_up_before_anything_changed(answer):
    r, sent, _ = make()
    r.start(0.0)
    if answer is not None:
        r.on_command_ack(ack(answer))
        r.tick(0.05)
    else:
        r.tick(ACK_TIMEOUT_S - 0.01)
        assert not r.gave_up
        r.tick(ACK_TIMEOUT_S)
    assert r.gave_up and not r.publish_new_heading and sent == [2]


def test_the_switch_back_is_retried_and_the_operator_told_when_never_confirmed():
    r, sent, warnings = make()
    r.start(0.0)
    r.on_command_ack(ack(mavlink.MAV_RESULT_ACCEPTED))
    r.tick(0.0)
    t = SWITCH_BACK_S
    r.tick(t)
    for _ in range(3):
        t += ACK_TIMEOUT_S
        r.tick(t)
    assert sent == [2, 1, 1, 1]
    assert len(warnings) == 1 and "set 2" in warnings[0] and len(warnings[0]) <= 50   # one STATUSTEXT
    assert r.publish_new_heading                         # the new heading stays: it is the right one


def test_config_needs_a_valid_alternate_set_for_source_set_mode():
    assert OutputsConfig.parse({"restart_yaw": "source_set", "ardupilot_source_set": 2}).ardupilot_source_set == 2
    for bad in ({"restart_yaw": "source_set"}, {"ardupilot_source_set": 1}, {"ardupilot_source_set": True},
                {"ardupilot_source_set": 2.0}, {"restart_yaw": "reset"}):
        with pytest.raises(ConfigError):
            OutputsConfig.parse(bad)
    with pytest.raises(ValueError):
        SourceSetRealign(1, print, print)


# -- the check of the autopilot's EK3_SRC parameters before any switch (daemon.source_set_check) -------------

def _param(name, value):
    return mavlink.MAVLink_param_value_message(name.encode(), value, mavlink.MAV_PARAM_TYPE_INT8, 900, 0)


def _answers(check, sets):
    """Answer every request of the last round from `sets` {set: (POSXY, VELXY, POSZ, VELZ, YAW)}."""
    for name in check.names:
        check.on_param_value(_param(name, float(sets[int(name[7])][AXES.index(name[9:])])))


@pytest.mark.parametrize("sets, allowed, why", [
    ({1: (3, 3, 1, 3, 6), 2: (3, 3, 1, 3, 0)}, True, "equal set 1"),
    ({1: (3, 3, 1, 3, 6), 2: (3, 3, 1, 3, 6)}, False, "6 too"),
    ({1: (3, 3, 1, 3, 1), 2: (3, 3, 1, 3, 0)}, False, "EK3_SRC1_YAW is 1"),
    ({1: (3, 3, 1, 3, 6), 2: (3, 0, 1, 3, 0)}, False, "VELXY"),
    ({1: (3, 3, 1, 3, 6), 2: (3, 3, 2, 3, 0)}, False, "POSZ"),
])
def test_the_switch_is_allowed_only_when_the_sets_differ_in_the_yaw_alone(sets, allowed, why):
    sent = []
    check = SourceSetCheck(2, sent.append, lambda: (7, 1))
    check.on_autopilot_heartbeat()
    assert sorted(m.param_id for m in sent) == sorted(f"EK3_SRC{s}_{a}" for s in (1, 2) for a in AXES)
    assert {(m.target_system, m.target_component, m.param_index) for m in sent} == {(7, 1, -1)}
    assert check.verdict is None and not check.allowed
    _answers(check, sets)
    assert check.allowed is allowed and why in check.verdict[1]


@pytest.mark.parametrize("alternate_yaw, advised", [(0, True), (1, True), (8, False)])
def test_an_alternate_yaw_of_none_is_allowed_but_gsf_is_advised(alternate_yaw, advised, caplog):
    """EKF3 stops aiding and resets velocity, position and height at a switch to a set whose yaw is None while
    disarmed on the ground (setAidingMode, AP_NavEKF3_Control.cpp; ArduPilot 4.8-dev SITL, issue 30), and Compass
    is None without an enabled compass: the switch still re-aligns, so it is allowed, with a warning naming 8."""
    check = SourceSetCheck(2, lambda m: None, lambda: (1, 1))
    check.on_autopilot_heartbeat()
    with caplog.at_level("WARNING", logger="ahrsd.daemon.source_set_check"):
        _answers(check, {1: (3, 3, 1, 3, 6), 2: (3, 3, 1, 3, alternate_yaw)})
    assert check.allowed
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    if advised:
        assert len(warned) == 1 and f"EK3_SRC2_YAW is {alternate_yaw}" in warned[0] and "EK3_SRC2_YAW = 8" in warned[0]
    else:
        assert not warned and check.advice is None


def test_missing_or_invalid_answers_are_asked_again_then_the_switch_is_refused():
    sent = []
    check = SourceSetCheck(3, sent.append, lambda: (1, 1))
    check.on_autopilot_heartbeat()
    check.on_param_value(_param("EK3_SRC1_YAW", 6.0))
    check.on_param_value(_param("EK3_SRC3_YAW", math.nan))          # hostile: ignored, asked again
    check.on_param_value(_param("SOMETHING_ELSE", 1.0))
    sent.clear()
    check.on_autopilot_heartbeat()
    assert len(sent) == 9 and "EK3_SRC1_YAW" not in [m.param_id for m in sent]
    for _ in range(MAX_REQUESTS):
        check.on_autopilot_heartbeat()
    assert check.verdict is not None and not check.allowed and "EK3_SRC3_YAW" in check.verdict[1]
