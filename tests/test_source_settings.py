"""drivers.source_settings: the settings drivers.source builds a sensor source from, declared by type (issue #29),
the daemon's [sensor] table one of them, and the reader child handed a plain copy."""

from __future__ import annotations

import dataclasses
import pickle

from ahrsd.daemon.config import SensorConfig
from ahrsd.drivers.source_settings import SensorSettings

# one value for every setting drivers.source reads, none at its default (written out, not derived from the class)
EVERY_SETTING = {"source": "spi", "scenario": "boat", "seed": 5, "errors": "ideal", "spi_device": "/dev/spidev1.0",
                 "data_ready": "gpiochip0:25", "iio_device": "iio:device1", "reader": "thread",
                 "replay_file": "r.csv", "replay_realtime": False, "replay_speed": 2.0, "rate_hz": 409.6}


def test_every_setting_the_drivers_read_is_a_sensor_key():
    """A setting drivers.source reads that `[sensor]` could not set would be a default no user can change."""
    assert set(EVERY_SETTING) == {f.name for f in dataclasses.fields(SensorSettings)}
    cfg = SensorConfig.parse(dict(EVERY_SETTING))
    assert isinstance(cfg, SensorSettings)
    assert {name: getattr(cfg, name) for name in EVERY_SETTING} == EVERY_SETTING


def test_the_rate_asked_by_default():
    """None asks the chip for no rate (its own SMPL_PRD); the daemon asks for the chip's default, 819.2 SPS."""
    assert SensorSettings().rate_hz is None
    assert SensorConfig().rate_hz == 819.2


def test_the_reader_child_gets_every_driver_setting_and_nothing_of_the_daemon():
    cfg = SensorConfig(**{**EVERY_SETTING, "reader": "process"}, mounting_rpy_deg=(0.0, 90.0, 0.0), poll_hz=100.0,
                       stale_timeout_s=0.5)
    child = cfg.read_in_thread()
    assert type(child) is SensorSettings
    assert child == SensorSettings(source="spi", scenario="boat", seed=5, errors="ideal",
                                   spi_device="/dev/spidev1.0", data_ready="gpiochip0:25", iio_device="iio:device1",
                                   reader="thread", replay_file="r.csv", replay_realtime=False, replay_speed=2.0,
                                   rate_hz=409.6)
    # unpickled in the child without importing the daemon's config (and all it imports)
    assert b"ahrsd.daemon" not in pickle.dumps(child)
