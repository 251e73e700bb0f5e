"""ahrsd.drivers: SPI buses, the ADIS16405 driver, the byte-level simulated chip, recordings."""

from .adis16405 import Adis16405
from .errors import BusError, ConfigError, DriverError, FrameError, ProductIdMismatch, SelfTestFailed, ShortRead
from .faults import Fault, FaultKind, FaultPlan
from .recording import RECORDING_HEADER, Recording, RecordingFormatError, RecordingWriter, iter_samples, read_recording
from .spi import SpiBus, SpidevBus

__all__ = [
    "Adis16405", "SimulatedAdis16405", "FixedStream", "SpiBus", "SpidevBus",
    "Fault", "FaultKind", "FaultPlan",
    "RECORDING_HEADER", "Recording", "RecordingFormatError", "RecordingWriter", "read_recording", "iter_samples",
    "DriverError", "BusError", "FrameError", "ShortRead", "ProductIdMismatch", "SelfTestFailed", "ConfigError",
]


def __getattr__(name):
    # The simulated chip is imported on first use, so `python -m ahrsd.drivers.simulated` (the benchmark)
    # does not find it half-imported.
    if name in ("SimulatedAdis16405", "FixedStream"):
        from . import simulated

        return getattr(simulated, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
