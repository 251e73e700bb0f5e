"""[gnss] config: every bad key names the key, the value and what is allowed; the estimator follows the source;
the command-line flags of `ahrsd run` map onto the same keys."""

from __future__ import annotations

import pytest

from ahrsd.daemon.config import Config, ConfigError, parse_config


def test_default_is_no_gnss_and_mekf():
    cfg = Config()
    assert cfg.gnss.source == "none" and cfg.gnss.lever_arm_m == (0.0, 0.0, 0.0)
    assert cfg.estimator_name == "mekf"


def test_keys_parse():
    cfg = parse_config({"gnss": {"source": "serial", "device": "/dev/serial0", "baud": 9600, "protocol": "nmea",
                                 "latency_s": 0.2, "lever_arm_m": [0.5, -0.25, -1.0]}})
    g = cfg.gnss
    assert (g.source, g.device, g.baud, g.protocol, g.latency_s, g.lever_arm_m) == (
        "serial", "/dev/serial0", 9600, "nmea", 0.2, (0.5, -0.25, -1.0))


@pytest.mark.parametrize("doc, key, hint", [
    ({"gnss": {"source": "usb"}}, "gnss.source", "'mavlink'"),
    ({"gnss": {"source": "serial"}}, "gnss.device", "required"),
    ({"gnss": {"device": "serial0"}}, "gnss.device", "/dev/"),
    ({"gnss": {"baud": 1234}}, "gnss.baud", "115200"),
    ({"gnss": {"baud": True}}, "gnss.baud", "115200"),
    ({"gnss": {"baud": 9600.5}}, "gnss.baud", "115200"),
    ({"gnss": {"protocol": "sirf"}}, "gnss.protocol", "'ubx'"),
    ({"gnss": {"latency_s": -0.1}}, "gnss.latency_s", "[0, 2]"),
    ({"gnss": {"source": "replay"}}, "gnss.file", "required"),
    ({"gnss": {"lever_arm_m": [0, 1]}}, "gnss.lever_arm_m", "three numbers"),
    ({"gnss": {"lever_arm_m": [0, 1, 1e3]}}, "gnss.lever_arm_m[2]", "[-100, 100]"),
    ({"gnss": {"lever_arm_m": [0, "a", 0]}}, "gnss.lever_arm_m[1]", "number"),
    ({"gnss": {"use_fused": 1}}, "gnss.use_fused", "true or false"),
    ({"gnss": {"baudrate": 9600}}, "gnss.baudrate", "allowed keys are"),
    ({"sensor": {"replay_speed": 0}}, "sensor.replay_speed", "[0.01, 100]"),
])
def test_bad_values_name_the_key(doc, key, hint):
    with pytest.raises(ConfigError) as exc:
        parse_config(doc)
    assert key in str(exc.value) and hint in str(exc.value)


def test_replay_and_sim_need_the_matching_sensor_source():
    with pytest.raises(ConfigError, match="gnss.source.*sensor.*replay"):
        Config().with_overrides(sim="static", gnss_replay="x.gnss.csv")
    with pytest.raises(ConfigError, match="gnss.source.*sensor.*sim"):
        Config().with_overrides(replay="x.csv", gnss_sim=True)
    cfg = Config().with_overrides(replay="x.csv", gnss_replay="x.gnss.csv", replay_speed=5)
    assert (cfg.gnss.source, cfg.gnss.file, cfg.sensor.replay_speed) == ("replay", "x.gnss.csv", 5.0)


def test_gnss_serial_flag():
    cfg = Config().with_overrides(gnss_serial="/dev/ttyACM0,9600")
    assert (cfg.gnss.source, cfg.gnss.device, cfg.gnss.baud) == ("serial", "/dev/ttyACM0", 9600)
    assert Config().with_overrides(gnss_serial="/dev/ttyACM0").gnss.baud == 115200
    for bad, hint in (("/dev/ttyACM0,1234", "BAUD"), ("ttyACM0", "/dev/")):
        with pytest.raises(ConfigError, match="--gnss-serial") as exc:
            Config().with_overrides(gnss_serial=bad)
        assert hint in str(exc.value)
    with pytest.raises(ConfigError, match="mutually exclusive"):
        Config().with_overrides(gnss_serial="/dev/ttyACM0", gnss_sim=True)
    with pytest.raises(ConfigError, match="--replay-speed"):
        Config().with_overrides(replay="x.csv", replay_speed=-1)


@pytest.mark.parametrize("source, extra", [("mavlink", {}), ("serial", {"device": "/dev/serial0"}),
                                           ("sim", {})])
def test_estimator_is_ins_when_gnss_is_configured(source, extra):
    assert parse_config({"gnss": {"source": source, **extra}}).estimator_name == "ins"


def test_explicit_estimator_wins():
    cfg = parse_config({"gnss": {"source": "mavlink"}, "estimator": {"name": "mekf"}})
    assert cfg.estimator_name == "mekf"
    assert Config().with_overrides(estimator="thesis").estimator_name == "thesis"
    assert parse_config({"gnss": {"source": "none"}}).estimator_name == "mekf"
