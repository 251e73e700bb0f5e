"""Config validation: every bad key names the key, the value and what is allowed; unknown keys rejected."""

from __future__ import annotations

import pytest

from ahrsd.daemon.config import Config, ConfigError, load_config, parse_config

REPO_EXAMPLE = __import__("pathlib").Path(__file__).resolve().parents[1] / "systemd" / "ahrsd.toml"


def test_defaults_are_the_embedded_simulator():
    cfg = Config()
    assert cfg.sensor.source == "sim" and cfg.sensor.scenario == "static"
    assert [e.url for e in cfg.endpoints] == ["udpout:127.0.0.1:14550"]
    assert (cfg.outputs.attitude_hz, cfg.outputs.attitude_quaternion_hz, cfg.outputs.vision_position_estimate_hz,
            cfg.outputs.highres_imu_hz, cfg.outputs.scaled_imu_hz, cfg.outputs.sys_status_hz) == (
        50.0, 10.0, 30.0, 10.0, 0.0, 1.0)
    assert cfg.mavlink.component_id == 200 and cfg.mavlink.system_id == 0


def test_annotated_example_parses():
    cfg = load_config(REPO_EXAMPLE)
    assert cfg.sensor.source == "spi" and cfg.sensor.spi_device == "/dev/spidev0.0"
    assert cfg.endpoints[0].url == "udpout:127.0.0.1:14655"


@pytest.mark.parametrize("doc, key, hint", [
    ({"sensor": {"source": "usb"}}, "sensor.source", "one of"),
    ({"sensor": {"scenario": "loop"}}, "sensor.scenario", "static"),
    ({"sensor": {"mounting_rpy_deg": [0, 95, 0]}}, "sensor.mounting_rpy_deg[1]", "[-90, 90]"),
    ({"sensor": {"mounting_rpy_deg": [0, 0]}}, "sensor.mounting_rpy_deg", "three angles"),
    ({"sensor": {"seed": 1.5}}, "sensor.seed", "integer"),
    ({"sensor": {"source": "replay"}}, "sensor.replay_file", "required"),
    ({"estimator": {"name": "ukf"}}, "estimator.name", "'mekf'"),
    ({"location": {"lat_deg": 91}}, "location.lat_deg", "[-90, 90]"),
    ({"location": {"lat_deg": 45}}, "location.lon_deg", "together"),
    ({"mavlink": {"component_id": 0}}, "mavlink.component_id", "[1, 255]"),
    ({"mavlink": {"system_id": True}}, "mavlink.system_id", "integer"),
    ({"outputs": {"attitude_hz": -1}}, "outputs.attitude_hz", "[0, 200]"),
    ({"outputs": {"vision_position_estimate_hz": 100}}, "outputs.vision_position_estimate_hz", "[0, 50]"),
    ({"outputs": {"attitude_hz": "fast"}}, "outputs.attitude_hz", "number"),
    ({"endpoint": [{"url": "udp-out:1.2.3.4:5"}]}, "endpoint[0].url", "pymavlink URL"),
    ({"endpoint": [{"url": "udpout:127.0.0.1:99999"}]}, "endpoint[0].url", "1..65535"),
    ({"endpoint": [{"url": "/dev/ttyAMA0,fast"}]}, "endpoint[0].url", "BAUD"),
    ({"endpoint": [{}]}, "endpoint[0].url", 'required (e.g. url = "udpout:127.0.0.1:14550")'),
    ({"endpoint": ["udpout:127.0.0.1:14550"]}, "endpoint[0]", "a table with key url"),
    ({"nmea": [{}]}, "nmea[0].url", 'required (e.g. url = "udp:127.0.0.1:10110")'),
    ({"nmea": ["udp:127.0.0.1:10110"]}, "nmea[0]", "a table with key url"),
    ({"signing": {"link_id": 300}}, "signing.link_id", "[0, 255]"),
    ({"daemon": {"status_line": "yes"}}, "daemon.status_line", "'auto'"),
])
def test_bad_values_name_key_value_and_allowed(doc, key, hint):
    with pytest.raises(ConfigError) as exc:
        parse_config(doc)
    msg = str(exc.value)
    assert key in msg and hint in msg


@pytest.mark.parametrize("doc, name", [
    ({"sensors": {}}, "[sensors]"),
    ({"sensor": {"sorce": "sim"}}, "sensor.sorce"),
    ({"outputs": {"attitude_rate": 5}}, "outputs.attitude_rate"),
    ({"endpoint": [{"url": "udpout:127.0.0.1:14550", "baud": 5}]}, "endpoint[0].baud"),
])
def test_unknown_keys_are_rejected_by_name(doc, name):
    with pytest.raises(ConfigError, match=r"unknown config") as exc:
        parse_config(doc)
    assert name in str(exc.value)


def test_file_errors_name_the_file(tmp_path):
    bad = tmp_path / "a.toml"
    bad.write_text("[sensor\nsource = 1")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(bad)
    with pytest.raises(ConfigError, match="does not exist"):
        load_config(tmp_path / "missing.toml")
    bad.write_text("[outputs]\nattitude_hz = 1000\n")
    with pytest.raises(ConfigError, match=str(bad)):
        load_config(bad)


def test_command_line_overrides_win_and_are_validated(tmp_path):
    cfg = parse_config({"sensor": {"source": "spi"}, "endpoint": [{"url": "udpout:10.0.0.1:14550"}]})
    over = cfg.with_overrides(sim="level-turns", mavlink=["udpin:0.0.0.0:14660", "/dev/ttyUSB0,57600"],
                              state_dir=str(tmp_path))
    assert over.sensor.source == "sim" and over.sensor.scenario == "level-turns"
    assert [e.url for e in over.endpoints] == ["udpin:0.0.0.0:14660", "/dev/ttyUSB0,57600"]
    assert over.state.resolve({}) == tmp_path
    with pytest.raises(ConfigError, match="--sim"):
        cfg.with_overrides(sim="nope")
    with pytest.raises(ConfigError, match="--mavlink"):
        cfg.with_overrides(mavlink=["localhost"])
    with pytest.raises(ConfigError, match="mutually exclusive"):
        cfg.with_overrides(sim="static", spi="/dev/spidev0.0")


def test_state_dir_resolution():
    from ahrsd.daemon.config import StateConfig

    assert str(StateConfig().resolve({"STATE_DIRECTORY": "/var/lib/ahrsd"})) == "/var/lib/ahrsd"
    assert str(StateConfig().resolve({"XDG_STATE_HOME": "/x"})) == "/x/ahrsd"
    assert str(StateConfig("/s").resolve({"STATE_DIRECTORY": "/var/lib/ahrsd"})) == "/s"
