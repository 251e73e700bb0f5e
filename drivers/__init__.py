"""ahrsd.drivers: SPI buses, the ADIS16405 driver, the byte-level simulated chip, recordings."""

from .sample import ImuSample, SampleFlags, make_sample

__all__ = ["ImuSample", "SampleFlags", "make_sample"]
