"""Typed driver errors. Everything the driver raises on purpose is a DriverError."""

from __future__ import annotations


class DriverError(Exception):
    """Base class of every error the drivers raise on purpose."""


class BusError(DriverError):
    """The SPI bus failed (device node missing, permission, ioctl error, device gone)."""


class FrameError(DriverError):
    """A frame came back but cannot be trusted (garbage, inconsistent ND/EA bits, implausible values).

    The driver counts it (`counters`) before raising; the caller may simply read the next sample.
    """

    def __init__(self, message: str, raw: bytes = b""):
        super().__init__(message)
        self.raw = bytes(raw)


class ShortRead(FrameError):
    """The bus returned fewer bytes than were clocked out."""


class ProductIdMismatch(DriverError):
    """PRODUCT_ID is not 0x4015: wrong chip, wrong chip select, or no device answering."""

    def __init__(self, found: int, expected: int):
        self.found, self.expected = found, expected
        if found in (0x0000, 0xFFFF):
            hint = "no device is answering: check power, wiring (MISO/MOSI/SCLK/CS), SPI mode 3 and the device path"
        elif found == 0x4010:
            hint = "this is an ADIS16400 (no magnetometer)"
        else:
            hint = "another device is on this chip select, or the bus is corrupting frames"
        super().__init__(f"PRODUCT_ID reads 0x{found:04X}, expected 0x{expected:04X} (ADIS16405): {hint}")


class SelfTestFailed(DriverError):
    """The internal self-test reported failures (DIAG_STAT) or did not finish in time."""

    def __init__(self, diag_stat: int, faults: list[str], message: str | None = None):
        self.diag_stat, self.faults = diag_stat, list(faults)
        super().__init__(message or f"self-test failed: DIAG_STAT=0x{diag_stat:04X} ({', '.join(faults) or 'no bits'})")


class ConfigError(DriverError, ValueError):
    """An invalid driver setting (sample rate, filter taps, gyro range)."""
