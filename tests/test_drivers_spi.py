"""SpidevBus on a stand-in spidev module; the simulated chip's checks of the SPI clock rule."""

import errno
import sys
import types

import numpy as np
import pytest

from ahrsd.drivers import registers as R
from ahrsd.drivers.errors import BusError
from ahrsd.drivers.simulated import SimulatedAdis16405
from sim_streams import FixedStream
from ahrsd.drivers.spi import SpidevBus


class FakeSpiDev:
    instances = []

    def __init__(self):
        self.calls = []
        self.fail = None
        FakeSpiDev.instances.append(self)

    def open_path(self, path):
        if path == "/dev/missing":
            raise FileNotFoundError(errno.ENOENT, "No such file or directory")
        if path == "/dev/denied":
            raise PermissionError(errno.EACCES, "Permission denied")
        self.path = path

    def xfer2(self, values, speed_hz=0, delay_usec=0, bits_per_word=0):
        if self.fail:
            raise OSError(self.fail, "ioctl failed")
        self.calls.append((list(values), speed_hz, delay_usec))
        return [0x40, 0x15][: len(values)] + [0] * max(0, len(values) - 2)

    def close(self):
        self.closed = True


@pytest.fixture
def fake_spidev(monkeypatch):
    FakeSpiDev.instances.clear()
    monkeypatch.setitem(sys.modules, "spidev", types.SimpleNamespace(SpiDev=FakeSpiDev))
    return FakeSpiDev


def test_spidev_bus_sets_mode_3_and_passes_speed_and_stall(fake_spidev):
    bus = SpidevBus("/dev/spidev0.0")
    dev = fake_spidev.instances[0]
    assert dev.mode == 3 and dev.bits_per_word == 8 and dev.lsbfirst is False
    rx = bus.transfer(b"\x56\x00", 300_000, 50)
    assert rx == b"\x40\x15" and isinstance(rx, bytes)
    assert dev.calls == [([0x56, 0x00], 300_000, 50)]
    dev.fail = errno.ENODEV
    with pytest.raises(BusError, match="spidev0.0"):
        bus.transfer(b"\x00\x00", 300_000)
    bus.close()
    assert dev.closed


@pytest.mark.parametrize("path, message", [("/dev/missing", "does not exist"), ("/dev/denied", "no permission")])
def test_spidev_open_errors_say_what_to_do(fake_spidev, path, message):
    with pytest.raises(BusError, match=message):
        SpidevBus(path)


def test_spidev_missing_module_is_a_clear_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "spidev", None)      # import spidev -> ImportError
    # the interpreter's own pip and the package: ahrsd is on no registry, so `pip install 'ahrsd[spi]'` (the old
    # hint, walk30) finds nothing
    with pytest.raises(BusError) as info:
        SpidevBus("/dev/spidev0.0")
    assert f"{sys.executable} -m pip install 'spidev>=3.6'" in str(info.value) and "ahrsd[" not in str(info.value)


def test_gpio_missing_module_is_a_clear_error(monkeypatch):
    from ahrsd.drivers.data_ready import open_gpio_line

    monkeypatch.setitem(sys.modules, "gpiod", None)
    with pytest.raises(BusError) as info:
        open_gpio_line("gpiochip0:25")
    assert f"{sys.executable} -m pip install 'gpiod>=2.1'" in str(info.value) and "ahrsd[" not in str(info.value)


def test_simulated_chip_catches_clock_rule_violations():
    chip = SimulatedAdis16405(FixedStream())
    chip.transfer(R.read_frame(R.PRODUCT_ID), 2_000_000)         # divisor 1: 2 MHz is allowed
    assert chip.stats["clock_violations"] == 0
    for frame in R.write_frames(R.SMPL_PRD, 0x0A):               # divisor 0x0A: 300 kHz only
        chip.transfer(frame, 2_000_000)
    chip.transfer(R.read_frame(R.PRODUCT_ID), 300_000)
    assert chip.stats["clock_violations"] == 0
    rx = chip.transfer(R.read_frame(R.PRODUCT_ID), 2_000_000)    # too fast: corrupted answer, SPI failure latched
    assert rx != b"\x40\x15" and chip.stats["clock_violations"] == 1
    chip.transfer(R.BURST_COMMAND + bytes(24), 2_000_000)         # bursts: 1 MHz at most
    assert chip.stats["clock_violations"] == 2
    chip.transfer(R.read_frame(R.DIAG_STAT), 300_000)
    assert int.from_bytes(chip.transfer(b"\x00\x00", 300_000), "big") & R.DiagStat.SPI_FAILURE


def test_odd_length_transfer_latches_spi_failure():
    chip = SimulatedAdis16405(FixedStream())
    assert chip.transfer(b"\x56", 300_000) == b"\x00"
    chip.transfer(R.read_frame(R.DIAG_STAT), 300_000)
    assert int.from_bytes(chip.transfer(b"\x00\x00", 300_000), "big") == R.DiagStat.SPI_FAILURE


def test_record_over_spidev_reaches_the_chip_through_the_real_backend(monkeypatch, tmp_path):
    """`ahrsd record --spi` end to end, with spidev replaced by a shim that forwards to the simulated chip."""
    from ahrsd.cli.main import main
    from ahrsd.drivers.recording import read_recording

    import time

    chip = SimulatedAdis16405(FixedStream(gyro_rad_s=(0.01, 0.02, -0.03)), clock=time.monotonic)  # a real-time chip

    class ChipSpiDev(FakeSpiDev):
        def xfer2(self, values, speed_hz=0, delay_usec=0, bits_per_word=0):
            assert self.mode == 3
            return list(chip.transfer(bytes(values), speed_hz, delay_usec))

    monkeypatch.setitem(sys.modules, "spidev", types.SimpleNamespace(SpiDev=ChipSpiDev))
    out = tmp_path / "spi.csv"
    assert main(["record", "--spi", "/dev/spidev0.0", "--seconds", "0.1", "--output", str(out), "--quiet"]) == 0
    rec = read_recording(out)
    assert len(rec) == round(0.1 * 819.202)
    assert "truth_qw" not in rec.columns and "flags" in rec.columns
    assert abs(rec.gyro_rad_s[:, 2].mean() + 0.03) < R.GYRO_RAD_S_PER_LSB
    assert chip.stats["clock_violations"] == 0 and chip.stats["bursts"] >= len(rec)
    counters = rec["counter"].astype(int)
    assert np.all(np.diff(counters) >= 1)          # fresh samples only, any lost ones show as counter jumps
