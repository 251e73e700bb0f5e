"""`[sensor] rate_hz` / `ahrsd run --rate-hz`: the chip's output data rate, written to its SMPL_PRD.

The register values are worked from the ADIS16405 datasheet (SMPL_PRD: t_S = t_B (N_S + 1), t_B = 1/1638.4 s with
bit 7 clear), not from the code: 204.8 SPS is 1638.4 / 8, N_S = 7; 300 SPS lies between N_S = 4 (327.68 SPS) and
N_S = 5 (273.07 SPS), and |ln(327.68/300)| = 0.088 < |ln(273.07/300)| = 0.094: the nearest setting is 4; 102.4 is
1638.4 / 16 and 12.8 is 1638.4 / 128, the largest divisor. The daemon reading the chip at the rate it set (the
status line's measured rate): tests/test_integration_daemon.py, on its module's daemon at 204.8 SPS.
"""

from __future__ import annotations

import time

import pytest

from ahrsd.daemon.config import Config, ConfigError, SensorConfig
from ahrsd.drivers import registers as R
from ahrsd.drivers.source import open_source


def read_smpl_prd(chip) -> int:
    """SMPL_PRD as a host reads it over the chip's SPI bytes: the address, then the value in the next frame."""
    chip.transfer(R.read_frame(R.SMPL_PRD), R.SPI_SLOW_HZ, 50)
    rx = chip.transfer(R.read_frame(R.PRODUCT_ID), R.SPI_SLOW_HZ, 50)
    return int.from_bytes(rx, "big")


@pytest.mark.parametrize("rate_hz, smpl_prd", [(204.8, 0x07), (300.0, 0x04), (102.4, 0x0F), (819.2, 0x01),
                                               (12.8, 0x7F)])
def test_the_nearest_smpl_prd_is_the_datasheets(rate_hz, smpl_prd):
    assert R.smpl_prd_for_rate(rate_hz) == smpl_prd
    assert R.nearest_rate_hz(rate_hz) == pytest.approx(1638.404 / (smpl_prd + 1), rel=1e-12)


def test_the_chip_is_set_to_the_nearest_smpl_prd_and_set_again_after_a_power_loss():
    rate_hz, smpl_prd = 204.8, 0x07
    src = open_source(SensorConfig(source="sim", reader="event_loop", rate_hz=rate_hz), clock=time.monotonic)
    try:
        chip = src.chip
        assert read_smpl_prd(chip) == smpl_prd
        assert src.sample_rate_hz == pytest.approx(1638.404 / (smpl_prd + 1), rel=1e-12)
        chip.power_cycle()                            # power lost: the chip is back at its flash setting
        assert read_smpl_prd(chip) == 0x01
        src.inner._try_open(time.monotonic())         # the re-open after the bus failure that follows
        assert read_smpl_prd(chip) == smpl_prd
    finally:
        src.close()
        src.chip.close()


@pytest.mark.parametrize("doc, hint", [
    ({"rate_hz": 900.0}, "[12.8, 819.2]"),
    ({"rate_hz": 12.0}, "[12.8, 819.2]"),
    ({"rate_hz": 40.0}, "stale_timeout_s"),              # 5 periods of 39.96 SPS = 0.125 s > 0.1 s
    ({"rate_hz": "fast"}, "a number"),
    # 12.81's nearest setting is SMPL_PRD 0x7F (12.80003 SPS: |ln(12.81/12.80003)| = 0.0008 < |ln(12.90082/12.81)|
    # = 0.0071), which the kernel driver's set_freq makes its slow base's 10.570 SPS (tests/test_iio_rate.py):
    # 5 periods are 0.473 s > 0.45 s, where the spidev path's 12.8 SPS would fit (0.391 s)
    ({"source": "iio", "rate_hz": 12.81, "stale_timeout_s": 0.45}, "stale_timeout_s"),
    ({"source": "replay", "replay_file": "r.csv", "rate_hz": 204.8}, "recorded at"),
])
def test_a_rate_the_chip_or_the_source_cannot_have_is_refused_by_name(doc, hint):
    with pytest.raises(ConfigError) as exc:
        SensorConfig.parse(doc)
    assert "sensor.rate_hz" in str(exc.value) and hint in str(exc.value)


def test_the_flag_is_checked_as_the_key_is_and_a_replay_refuses_the_files_rate():
    assert Config().with_overrides(rate_hz=204.8).sensor.chip_rate_hz == pytest.approx(1638.404 / 8, rel=1e-12)
    assert SensorConfig.parse({"rate_hz": 40.0, "stale_timeout_s": 0.2}).chip_rate_hz == \
        pytest.approx(1638.404 / 41, rel=1e-12)          # N_S = 40: 39.96 SPS, 5 periods = 0.125 s < 0.2 s
    with pytest.raises(ConfigError, match=r"--rate-hz.*recorded at"):
        Config().with_overrides(rate_hz=204.8, replay="r.csv")
    with pytest.raises(ConfigError, match=r"--rate-hz.*819.2"):
        Config().with_overrides(rate_hz=1000.0)
    from_file = Config(sensor=SensorConfig.parse({"rate_hz": 204.8}))
    assert from_file.with_overrides(iio="iio:device0").sensor.rate_hz == 204.8     # the driver's sampling_frequency
    assert SensorConfig.parse({"source": "iio", "rate_hz": 12.81, "stale_timeout_s": 0.5}).rate_hz == 12.81


def test_run_time_faults_start_on_the_grid_of_the_written_rate():
    """--sim-faults counts samples from the first read at the configured rate (drivers.ground_truth rebases the
    plan there): the plan's sample 0 is the first sample whose data-ready edge comes after that read on the
    chip's grid (0.3 s at 819.2 SPS from power-on to the start, which wrote SMPL_PRD 7, then 204.85 SPS) — not
    1.8 s × 204.85 + 1, as if one rate had run since power-on: 0.3 s × (819.2 − 204.85) = 184 samples short."""
    from sim_streams import FixedStream
    from support.stepped_clock import ManualClock

    from ahrsd.drivers.faults import FaultPlan
    from ahrsd.drivers.ground_truth import BurstIndexTap, GroundTruthSource
    from ahrsd.drivers.reconnecting import ReconnectingSource
    from ahrsd.drivers.simulated import SimulatedAdis16405
    from ahrsd.drivers.source import open_chip_driver

    clock = ManualClock(100.0)
    plan = FaultPlan(seed=0)
    fault = plan.add("stall", start_sample=0, stop_sample=10)
    later = plan.add("stall", start_sample=round(2.0 * 204.8))   # stall@2 (cli.fault_schedule: seconds × rate)
    chip = SimulatedAdis16405(FixedStream([0.0, 0.0, 0.0], [0.0, 0.0, -R.STANDARD_GRAVITY_M_S2], [20.0, 0.0, 45.0]),
                              clock=clock, faults=plan)
    tap = BurstIndexTap(chip)
    src = GroundTruthSource(ReconnectingSource(lambda: tap, open_chip_driver, "test chip", clock=clock,
                                               reopen_same_bus=True, sample_rate_hz=204.8), chip, tap)
    clock.t = 100.3                                       # the chip powered on 0.3 s before the daemon starts it
    src.start()
    assert read_smpl_prd(chip) == 0x07
    clock.t = 101.8
    src.read_one(clock.t)
    start = fault.start_sample                            # counted from the first read only, not from the start too
    assert chip.ready_clock_time(start - 1) <= 101.8 < chip.ready_clock_time(start)   # the chip's DIO1 edges
    assert chip.ready_clock_time(start) - chip.ready_clock_time(start - 1) == pytest.approx(8 / 1638.404)
    assert fault.stop_sample == fault.start_sample + 10
    assert start > int(1.8 * chip.sample_rate_hz) + 1 + 150       # the one-rate count is 184 samples short
    # the schedule's 2 s after the first read, within a sample (the start's base added too: 0.3 s × 819.2 later)
    assert chip.ready_clock_time(later.start_sample) == pytest.approx(101.8 + 2.0, abs=1.5 / 204.8)


def test_a_refused_rate_is_named_where_it_came_from_at_each_entry(tmp_path):
    """One rule (SensorConfig.check_rate), checked where the rate or the source can come from: the file (the error
    names the file and the key), --rate-hz (names the flag, also when the source is a flag), and --replay / --iio
    replacing the file's source under the file's rate (names the file's key). 5 periods of 39.96 SPS (SMPL_PRD
    N_S = 40: 1638.404 / 41) are 0.125 s, longer than the default stale_timeout_s 0.1 s; the kernel driver's
    10.570 SPS for 12.81 (tests/test_iio_rate.py) makes 0.473 s > 0.45 s."""
    from ahrsd.daemon.config import load_config

    toml = tmp_path / "ahrsd.toml"
    toml.write_text("[sensor]\nrate_hz = 40.0\n")
    with pytest.raises(ConfigError) as exc:
        load_config(toml)
    assert str(toml) in str(exc.value) and "sensor.rate_hz = 40.0" in str(exc.value) \
        and "stale_timeout_s" in str(exc.value)
    for flags, hint in (({"rate_hz": 40.0}, "stale_timeout_s"), ({"rate_hz": 204.8, "replay": "r.csv"}, "recorded at"),
                        ({"replay": "r.csv", "rate_hz": 409.6}, "recorded at")):
        with pytest.raises(ConfigError) as exc:
            Config().with_overrides(**flags)
        assert "--rate-hz = " in str(exc.value) and "sensor.rate_hz" not in str(exc.value) \
            and hint in str(exc.value), str(exc.value)
    from_file = Config(sensor=SensorConfig.parse({"rate_hz": 204.8}))
    with pytest.raises(ConfigError) as exc:
        from_file.with_overrides(replay="r.csv")
    assert "sensor.rate_hz = 204.8" in str(exc.value) and "recorded at" in str(exc.value)
    slow_iio = Config(sensor=SensorConfig.parse({"rate_hz": 12.81, "stale_timeout_s": 0.45}))   # fine on spidev
    with pytest.raises(ConfigError) as exc:
        slow_iio.with_overrides(iio="iio:device0")
    assert "sensor.rate_hz = 12.81" in str(exc.value) and "stale_timeout_s" in str(exc.value)
