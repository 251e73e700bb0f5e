"""SPI buses: the minimal protocol the ADIS16405 driver talks to, and the real spidev backend.

One `transfer()` call is one chip-select assertion: full duplex, `len(rx) == len(tx)` on a healthy bus.
Nothing here knows about the ADIS16405.
"""

from __future__ import annotations

import shlex
import sys
import time
from typing import Protocol, runtime_checkable

from .errors import BusError

SPI_MODE_3 = 0b11  # CPOL=1, CPHA=1 (ADIS16405 datasheet SPI timing; kernel adis16400.c)


@runtime_checkable
class SpiBus(Protocol):
    """Full-duplex SPI: send `tx` with chip select held, return the bytes clocked in."""

    def transfer(self, tx: bytes, speed_hz: int, delay_us: int = 0) -> bytes:
        """One CS-asserted transfer at `speed_hz`; `delay_us` is the stall after it before CS may assert again."""
        ...

    def sleep(self, seconds: float) -> None:
        """Wait `seconds` for the chip (a reset, the self-test): the host's time on a real bus, the chip's own
        (virtual) time on the simulated one."""
        ...

    def close(self) -> None:
        ...


class SpidevBus:
    """A Linux `/dev/spidevB.C` node through the `spidev` module (mode 3, MSB first, 8-bit words).

    Importing this module never needs spidev; constructing a SpidevBus does, and says how to get it.
    """

    def __init__(self, path: str, mode: int = SPI_MODE_3, max_speed_hz: int = 2_000_000):
        try:
            import spidev  # noqa: PLC0415  (optional dependency: ahrsd[spi])
        except ImportError as exc:
            # ahrsd comes from its source tree, not a package registry: `pip install 'ahrsd[spi]'` finds nothing
            # there, so the hint names this interpreter (its virtualenv) and the package (pyproject's spi extra)
            raise BusError(
                "the 'spidev' module is not installed: install it with  "
                f"{shlex.quote(sys.executable)} -m pip install 'spidev>=3.6'  "
                "(Linux only; it needs the kernel spidev driver)"
            ) from exc
        self.path = path
        self._spi = spidev.SpiDev()
        try:
            self._spi.open_path(path)
        except (OSError, AttributeError) as exc:
            raise BusError(_open_hint(path, exc)) from exc
        try:
            self._spi.mode = mode
            self._spi.bits_per_word = 8
            self._spi.lsbfirst = False
            self._spi.max_speed_hz = max_speed_hz
        except OSError as exc:
            self._spi.close()
            raise BusError(f"cannot configure {path}: {exc}") from exc

    def transfer(self, tx: bytes, speed_hz: int, delay_us: int = 0) -> bytes:
        try:
            # xfer2 holds CS for the whole list (one frame / one burst); delay_usec is the stall after it.
            rx = self._spi.xfer2(list(tx), int(speed_hz), int(delay_us))
        except OSError as exc:
            raise BusError(f"SPI transfer on {self.path} failed: {exc}") from exc
        return bytes(rx)

    def sleep(self, seconds: float) -> None:
        time.sleep(seconds)

    def close(self) -> None:
        self._spi.close()

    def __repr__(self) -> str:
        return f"SpidevBus({self.path!r})"


def _open_hint(path: str, exc: BaseException) -> str:
    import errno
    import os

    code = getattr(exc, "errno", None)
    if code in (errno.EACCES, errno.EPERM):
        return (f"no permission to open {path}: add the user to the 'spi' group or install a udev rule "
                f"SUBSYSTEM==\"spidev\", GROUP=\"spi\", MODE=\"0660\" ({exc})")
    if code == errno.ENOENT or not os.path.exists(path):
        return (f"{path} does not exist: enable SPI (Raspberry Pi: dtparam=spi=on in config.txt) "
                f"and check the bus/chip-select numbers ({exc})")
    return f"cannot open {path}: {exc}"
