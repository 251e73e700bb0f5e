"""A simulated GNSS receiver: bytes on a pseudo-terminal, so the serial source runs exactly as on hardware.

`SimulatedGnssReceiver(fixes, protocol="ubx")` opens a pty (`os.openpty`); give `.device` (the slave path)
to `SerialGnssSource`. `start()` runs a thread that writes each fix as a UBX NAV-PVT (pyubx2) or as NMEA
RMC/VTG/GGA (pynmeagps) when `clock()` reaches `fix.t_s + latency_s`; `write_fix(fix)` writes one at once.

The receiver has its own baud rate. A pty has no baud rate, but its termios holds the one the reader set, so
when the two differ the bytes are re-timed as a UART at the reader's rate would sample the receiver's line
(`uart_resample`): a baud mismatch produces the same garbage as on a real wire. Faults for tests:
`garbage_bytes` random bytes before each fix, `truncate_every` (every n-th frame cut short),
`corrupt_every` (every n-th frame with one payload byte flipped), `silent` (write nothing).
"""

from __future__ import annotations

import datetime as dt
import os
import random
import termios
import threading
import time
import tty
from collections.abc import Callable, Sequence

import numpy as np

from .nmea import nmea_epoch_sentences
from .ubx import nav_pvt_message
from ahrsd.core.gnss import GnssFix

GPS_EPOCH = dt.datetime(1980, 1, 6, tzinfo=dt.timezone.utc)
DEFAULT_START_UTC = dt.datetime(2026, 6, 1, 12, 0, 0, tzinfo=dt.timezone.utc)
_TERMIOS_BAUD = {getattr(termios, f"B{b}"): b for b in (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200,
                                                         230400, 460800, 921600) if hasattr(termios, f"B{b}")}


def uart_resample(data: bytes, tx_baud: int, rx_baud: int) -> bytes:
    """The bytes a UART at `rx_baud` reads from a line driven at `tx_baud` with `data` (8N1, idle high).

    The receiver waits for a falling edge (start bit), samples the 8 data bits (LSB first) at the middle of
    each of its own bit times, and delivers the byte whatever the stop bit (Linux does without INPCK), then
    waits for the next falling edge. Equal rates return `data` unchanged.
    """
    if tx_baud == rx_baud or not data:
        return bytes(data)
    frames = np.unpackbits(np.frombuffer(bytes(data), np.uint8)[:, None], axis=1, bitorder="little")
    levels = np.concatenate([np.zeros((len(data), 1), np.uint8), frames, np.ones((len(data), 1), np.uint8)],
                            axis=1).ravel()                     # start 0, 8 data bits, stop 1
    n_bits = len(levels)
    falling = np.flatnonzero(np.diff(np.concatenate([[1], levels.astype(np.int16)])) == -1)   # 1 -> 0 at bit k
    bit_rx = tx_baud / rx_baud                                  # one rx bit in tx-bit units

    def level(t_tx_bits: float) -> int:
        k = int(t_tx_bits)
        return int(levels[k]) if k < n_bits else 1

    out = bytearray()
    t = 0.0
    while True:
        i = np.searchsorted(falling, t, side="left")
        if i >= len(falling):
            break
        edge = float(falling[i])
        if level(edge + 0.5 * bit_rx) != 0:                     # glitch, not a start bit
            t = edge + 1e-9
            continue
        value = 0
        for b in range(8):
            value |= level(edge + (1.5 + b) * bit_rx) << b
        out.append(value)
        t = edge + 9.5 * bit_rx                                 # look for the next start after the stop sample
    return bytes(out)


class SimulatedGnssReceiver:
    """A receiver writing `fixes` into a pty as UBX NAV-PVT ("ubx") or NMEA RMC/VTG/GGA ("nmea")."""

    def __init__(self, fixes: Sequence[GnssFix] = (), protocol: str = "ubx", baud: int = 115200,
                 latency_s: float = 0.0, clock: Callable[[], float] = time.monotonic,
                 start_utc: dt.datetime = DEFAULT_START_UTC, garbage_bytes: int = 0, truncate_every: int = 0,
                 corrupt_every: int = 0, silent: bool = False, seed: int = 0):
        if protocol not in ("ubx", "nmea"):
            raise ValueError(f"simulated receiver protocol must be 'ubx' or 'nmea', not {protocol!r}")
        self.fixes = list(fixes)
        self.protocol, self.baud, self.latency_s, self.clock = protocol, int(baud), float(latency_s), clock
        self.start_utc = start_utc
        self.garbage_bytes, self.truncate_every, self.corrupt_every = garbage_bytes, truncate_every, corrupt_every
        self.silent = silent
        self._rng = random.Random(seed)
        self.master_fd, self.slave_fd = os.openpty()
        tty.setraw(self.slave_fd)       # no echo, no line editing before the reader opens (and sets) it
        self.device = os.ttyname(self.slave_fd)
        self.frames_written = 0
        self.bytes_written = 0          # the receiver's bytes
        self.wire_bytes_written = 0     # what went into the pty (differs when re-timed for another baud rate)
        self._t0 = self.fixes[0].t_s if self.fixes else 0.0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------------------------------------ bytes
    def frames_for(self, fix: GnssFix) -> list[bytes]:
        """The frames a receiver sends for one epoch (the receiver's clock starts at the first fix)."""
        utc = self.start_utc + dt.timedelta(seconds=fix.t_s - self._t0)
        if self.protocol == "ubx":
            itow_ms = int(round((utc - GPS_EPOCH).total_seconds() * 1000.0)) % (7 * 86400 * 1000)
            return [nav_pvt_message(fix, itow_ms).serialize()]
        return [m.serialize() for m in nmea_epoch_sentences(fix, utc)]

    def reader_baud(self) -> int | None:
        """The baud rate the reader set on the slave (None if not a standard rate)."""
        return _TERMIOS_BAUD.get(termios.tcgetattr(self.slave_fd)[5])

    def write_bytes(self, data: bytes) -> None:
        """Put raw bytes on the line (re-timed if the reader's baud rate differs from the receiver's)."""
        rx_baud = self.reader_baud() or self.baud
        wire = uart_resample(data, self.baud, rx_baud)
        view = memoryview(wire)
        while view:
            n = os.write(self.master_fd, view)
            view = view[n:]
        self.bytes_written += len(data)
        self.wire_bytes_written += len(wire)

    def write_fix(self, fix: GnssFix) -> None:
        if self.silent:
            return
        data = bytearray(self._rng.randbytes(self.garbage_bytes)) if self.garbage_bytes else bytearray()
        for frame in self.frames_for(fix):
            self.frames_written += 1
            frame = bytearray(frame)
            if self.corrupt_every and self.frames_written % self.corrupt_every == 0:
                frame[len(frame) // 2] ^= 0x5A
            if self.truncate_every and self.frames_written % self.truncate_every == 0:
                frame = frame[: len(frame) // 2]
            data += frame
        self.write_bytes(bytes(data))

    # ------------------------------------------------------------------------------------------------ thread
    def start(self) -> "SimulatedGnssReceiver":
        """Write the fixes in a thread at clock() >= fix.t_s + latency_s."""
        self._thread = threading.Thread(target=self._run, name="sim-gnss", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        for fix in self.fixes:
            while not self._stop.is_set():
                wait = fix.t_s + self.latency_s - self.clock()
                if wait <= 0:
                    break
                self._stop.wait(min(wait, 0.05))
            if self._stop.is_set():
                return
            try:
                self.write_fix(fix)
            except OSError:            # the pty was closed under us
                return

    @property
    def done(self) -> bool:
        return self._thread is not None and not self._thread.is_alive()

    def join(self, timeout: float | None = None) -> None:
        if self._thread is not None:
            self._thread.join(timeout)

    def close(self) -> None:
        """Stop the thread and close the pty (the reader then sees the device gone)."""
        self._stop.set()
        self.join(5.0)
        for fd in (self.master_fd, self.slave_fd):
            try:
                os.close(fd)
            except OSError:
                pass
        self.master_fd = self.slave_fd = -1

    def __enter__(self) -> "SimulatedGnssReceiver":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
