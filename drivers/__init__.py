"""ahrsd.drivers: SPI buses, the ADIS16405 driver, the byte-level simulated chip, recordings, and the sensor
sources built on them (drivers.source: the SensorSource protocol and the factory)."""

from .adis16405 import Adis16405
from .errors import BusError, ConfigError, DriverError, FrameError, ProductIdMismatch, SelfTestFailed, ShortRead
from .faults import Fault, FaultKind, FaultPlan
from .recording import RECORDING_HEADER, Recording, RecordingFormatError, RecordingWriter, iter_samples, read_recording
from .spi import SpiBus, SpidevBus

__all__ = [
    "Adis16405", "SimulatedAdis16405", "SpiBus", "SpidevBus", "SensorSource", "open_source",
    "Fault", "FaultKind", "FaultPlan",
    "RECORDING_HEADER", "Recording", "RecordingFormatError", "RecordingWriter", "read_recording", "iter_samples",
    "DriverError", "BusError", "FrameError", "ShortRead", "ProductIdMismatch", "SelfTestFailed", "ConfigError",
]


def __getattr__(name):
    # The simulated chip and the sources (which build it) are imported on first use.
    if name == "SimulatedAdis16405":
        from . import simulated

        return simulated.SimulatedAdis16405
    if name in ("SensorSource", "open_source"):
        from . import source

        return getattr(source, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
