"""ahrsd.drivers: SPI buses, the ADIS16405 driver, the byte-level simulated chip, recordings."""

from .adis16405 import Adis16405
from .errors import BusError, ConfigError, DriverError, FrameError, ProductIdMismatch, SelfTestFailed, ShortRead
from .faults import Fault, FaultKind, FaultPlan
from .sample import ImuSample, SampleFlags, make_sample
from .simulated import SimulatedAdis16405
from .spi import SpiBus, SpidevBus

__all__ = [
    "ImuSample", "SampleFlags", "make_sample",
    "Adis16405", "SimulatedAdis16405", "SpiBus", "SpidevBus",
    "Fault", "FaultKind", "FaultPlan",
    "DriverError", "BusError", "FrameError", "ShortRead", "ProductIdMismatch", "SelfTestFailed", "ConfigError",
]
