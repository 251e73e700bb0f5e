"""The serial backend: a GNSS receiver on a UART/USB (pyserial) sending UBX NAV-PVT and/or NMEA.

The bytes go through the stream decoder (stream.GnssStreamDecoder); this adds the port, the time stamps and
the link health. As a `GnssBackend` (backend.py): `fileno()` is the port's descriptor (it changes when the
device is re-opened, -1 while it is lost), `read()` reads what is there and re-opens a lost device every
REOPEN_INTERVAL_S, `health()` tells silence, garbage (a baud mismatch), a wrong protocol and a lost device
apart. For tools that want the port at once: the constructor opens it and raises GnssDeviceError, unless
`missing_ok` (the daemon: the receiver may be plugged in later); `read_available()` and `poll_health()` are
the plain read and the once-a-second check.

Time stamping: each fix's arrival stamp is (the caller's clock when its last byte was read) − latency_s.
latency_s is the receiver's output latency (measurement epoch to the end of the message on the wire): the
navigation computation plus the transmission time of the epoch's messages at the baud rate (10 bits per
byte: a 100-byte NAV-PVT is 1000/baud s). A fix with the receiver's own epoch time (UBX iTOW, NMEA UTC) is
then stamped at that time plus the least-delayed offset seen (receiver_time.ReceiverTimeStamper), so a read
that was held up stamps nothing late and stamps never go backwards. docs/gnss.md has the figures.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable

import serial

from ..errors import DriverError
from .backend import GnssBackend, GnssHealth, GnssLinkState
from .receiver_time import ReceiverTimeStamper
from .stream import PROTOCOLS, GnssStreamDecoder
from ahrsd.core.gnss import GnssFix

log = logging.getLogger(__name__)

# ArduPilot's lag for u-blox 7/M8 "based on flight logs" (libraries/AP_GPS/AP_GPS_UBLOX.cpp, get_lag();
# 0.22 s for other or unknown generations), measured like ours from the message's arrival.
DEFAULT_LATENCY_S = 0.12
SILENCE_TIMEOUT_S = 3.0         # no byte for this long: the receiver says nothing
NO_FRAME_TIMEOUT_S = 3.0        # bytes but no valid frame for this long: garbage (baud mismatch?)
GARBAGE_MIN_BYTES = 64          # ...and at least this many bytes arrived in that time
REOPEN_INTERVAL_S = 2.0
READ_CHUNK = 4096
WEEK_S = 7 * 86400.0            # UBX iTOW wraps at the end of the GPS week
DAY_S = 86400.0                 # NMEA's UTC time of day wraps at midnight
MAX_READ_PER_CALL = 65536


class GnssDeviceError(DriverError):
    """The serial device cannot be opened (missing, permission, busy)."""


class SerialGnssSource(GnssBackend):
    """A GNSS receiver on `device` at `baud`, protocol "ubx" | "nmea" | "auto".

    `clock` is the time base of the fixes (the IMU samples' monotonic clock). Opening fails with
    GnssDeviceError, unless `missing_ok`: then a port that cannot be opened is a lost device from the start.
    `counters` (dict: bytes, frames, garbage bytes, rejected frames, checksum failures, read errors, ...).
    """

    def __init__(self, device: str, baud: int = 115200, protocol: str = "auto",
                 latency_s: float = DEFAULT_LATENCY_S, clock: Callable[[], float] = time.monotonic,
                 silence_timeout_s: float = SILENCE_TIMEOUT_S, no_frame_timeout_s: float = NO_FRAME_TIMEOUT_S,
                 missing_ok: bool = False):
        if protocol not in PROTOCOLS:
            raise ValueError(f"[gnss] protocol must be one of {', '.join(PROTOCOLS)}, not {protocol!r}")
        if not (isinstance(baud, int) and baud > 0):
            raise ValueError(f"[gnss] baud must be a positive integer, not {baud!r}")
        if not (math.isfinite(latency_s) and 0.0 <= latency_s < 2.0):
            raise ValueError(f"[gnss] latency_s must be in [0, 2) s, not {latency_s!r}")
        self.device, self.baud, self.protocol, self.latency_s = device, baud, protocol, float(latency_s)
        self.description = f"receiver on {device} at {baud} baud ({protocol})"
        self.clock = clock
        self.silence_timeout_s, self.no_frame_timeout_s = silence_timeout_s, no_frame_timeout_s
        self.decoder = GnssStreamDecoder(protocol, source=f"serial:{device}")
        self.read_errors = 0
        self.reopen_count = 0
        self.internal_errors = 0
        self._stampers: dict[float, ReceiverTimeStamper] = {}     # by the receiver time's wrap period
        self.state = GnssLinkState.WAITING
        self.status_message = f"{device}: waiting for data at {baud} baud ({protocol})"
        now = clock()
        self._opened_at = now
        self._last_byte_at = math.nan
        self._last_frame_at = math.nan
        self._last_fix_at = math.nan
        self._bytes_since_frame = 0
        self._last_open_try = now
        self._open_error = ""
        try:
            self._serial = self._open()
        except GnssDeviceError as exc:
            if not missing_ok:
                raise
            self._serial, self._open_error = None, str(exc)
            self._update_state(now)

    # ------------------------------------------------------------------------------------------------ API
    def fileno(self) -> int:
        """The file descriptor to wait on (-1 while the device is lost)."""
        return self._serial.fileno() if self._serial is not None else -1

    def read_available(self) -> list[GnssFix]:
        """Read every byte available now (never blocks) and return the fixes they complete."""
        if self._serial is None:
            return []
        fixes: list[GnssFix] = []
        total = 0
        while total < MAX_READ_PER_CALL:
            try:
                data = self._serial.read(max(self._serial.in_waiting, 1) if total == 0 else self._serial.in_waiting)
            # Unplugged: SerialException/OSError; a port closed under us: TypeError (pyserial's fd is None).
            except (serial.SerialException, OSError, TypeError) as exc:
                self._lost(exc)
                break
            if not data:
                break
            total += len(data)
            fixes += self._feed(data)
        self._update_state(self.clock())
        return self._stamp(fixes)

    def poll_health(self) -> GnssLinkState:
        """Re-evaluate the link state (call ~1 Hz); re-opens a lost device every REOPEN_INTERVAL_S."""
        now = self.clock()
        self._reopen_if_due(now)
        self._update_state(now)
        return self.state

    # ------------------------------------------------------------------------------------------------ backend
    def read(self) -> list[GnssFix]:
        """GnssBackend.read: re-open a lost device when due, then `read_available()`."""
        try:
            self._reopen_if_due(self.clock())
            return self.read_available()
        except Exception as exc:  # noqa: BLE001 - read() never raises (backend.py); a bug is counted
            self.internal_errors += 1
            log.exception("%s: reading failed: %s", self.device, exc)
            return []

    def health(self) -> GnssHealth:
        self._update_state(self.clock())
        return GnssHealth(self.state, self.status_message)

    def stats(self) -> dict[str, dict]:
        return {"serial": self.counters}

    @property
    def counters(self) -> dict:
        c = self.decoder.counters.as_dict()
        c.update(read_errors=self.read_errors, reopens=self.reopen_count, internal_errors=self.internal_errors,
                 receiver_clock_jumps=sum(s.receiver_clock_jumps for s in self._stampers.values()),
                 stamps_held=sum(s.stamps_held for s in self._stampers.values()))
        return c

    def close(self) -> None:
        if self._serial is not None:
            self._serial.close()
            self._serial = None

    def __enter__(self) -> "SerialGnssSource":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------------------------------------ internal
    def _reopen_if_due(self, now: float) -> None:
        if self._serial is not None or now - self._last_open_try < REOPEN_INTERVAL_S:
            return
        self._last_open_try = now
        try:
            self._serial = self._open()
        except GnssDeviceError as exc:
            self._open_error = str(exc)
            return
        self.reopen_count += 1
        self._open_error = ""
        log.info("%s: opened", self.device)

    def _open(self) -> serial.Serial:
        try:
            return serial.Serial(self.device, self.baud, timeout=0, exclusive=True)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise GnssDeviceError(f"cannot open GNSS receiver {self.device} at {self.baud} baud: {exc}") from exc

    def _feed(self, data: bytes) -> list[GnssFix]:
        now = self.clock()
        before = self.decoder.counters.frames_valid
        fixes = self.decoder.feed(data, now - self.latency_s)
        self._last_byte_at = now
        if self.decoder.counters.frames_valid > before:
            self._last_frame_at = now
            self._bytes_since_frame = 0
        else:
            self._bytes_since_frame += len(data)
        if fixes:
            self._last_fix_at = now
        return fixes

    def _stamp(self, fixes: list[GnssFix]) -> list[GnssFix]:
        """Each fix of one read at its receiver time + the least-delayed offset (receiver_time.py); one stamper
        per kind of receiver time (protocol "auto" may see NMEA epochs before the first NAV-PVT)."""
        periods = [_receiver_time_period_s(f) for f in fixes]
        out: list[GnssFix] = list(fixes)
        for period_s in dict.fromkeys(periods):
            stamper = self._stampers.get(period_s)
            if stamper is None:
                stamper = self._stampers[period_s] = ReceiverTimeStamper(period_s, name=self.device)
            at = [i for i, p in enumerate(periods) if p == period_s]
            for i, fix in zip(at, stamper.stamp_read([fixes[i] for i in at])):
                out[i] = fix
        return out

    def _lost(self, exc: Exception) -> None:
        self.read_errors += 1
        log.warning("%s: read failed (%s); will try to re-open", self.device, exc)
        try:
            self._serial.close()
        except Exception:          # closing a vanished device may fail too; it is gone either way
            pass
        self._serial = None
        self._last_open_try = self.clock()

    def _since(self, now: float, then: float) -> float:
        return now - (then if math.isfinite(then) else self._opened_at)

    def _update_state(self, now: float) -> None:
        c = self.decoder.counters
        dev = self.device
        if self._serial is None:
            state = GnssLinkState.DEVICE_ERROR
            msg = (f"{dev}: device lost ({self.read_errors} read errors), re-opening every {REOPEN_INTERVAL_S:.0f} s"
                   if self.read_errors else f"{dev}: cannot open, trying every {REOPEN_INTERVAL_S:.0f} s")
            if self._open_error:
                msg += f" (last attempt: {self._open_error})"
        elif self._since(now, self._last_byte_at) > self.silence_timeout_s:
            state = GnssLinkState.SILENT
            msg = (f"{dev}: no bytes for {self._since(now, self._last_byte_at):.0f} s: check the receiver's power, "
                   f"its TX wired to our RX, and that it outputs on this port")
        elif (self._since(now, self._last_frame_at) > self.no_frame_timeout_s
              and self._bytes_since_frame >= GARBAGE_MIN_BYTES):
            state = GnssLinkState.GARBAGE
            msg = (f"{dev}: {self._bytes_since_frame} bytes but no valid UBX/NMEA frame for "
                   f"{self._since(now, self._last_frame_at):.0f} s ({c.frames_rejected} rejected, "
                   f"{c.checksum_failures} checksum failures): baud mismatch? (configured {self.baud})")
        elif self._since(now, self._last_fix_at) > self.no_frame_timeout_s and c.frames_valid > 0:
            state = GnssLinkState.WRONG_PROTOCOL
            want = {"ubx": "UBX NAV-PVT", "nmea": "NMEA RMC/GGA/VTG", "auto": "UBX NAV-PVT or NMEA RMC/GGA/VTG"}
            msg = (f"{dev}: valid frames ({c.frames_ubx} UBX, {c.frames_nmea} NMEA) but no "
                   f"{want[self.protocol]}: enable that output on the receiver or set protocol")
        elif math.isfinite(self._last_fix_at):
            state, msg = GnssLinkState.OK, f"{dev}: {c.fixes} fixes, {c.frames_rejected} rejected frames"
        else:
            state, msg = GnssLinkState.WAITING, f"{dev}: waiting for data at {self.baud} baud ({self.protocol})"
        if state is not self.state:
            level = logging.INFO if state in (GnssLinkState.OK, GnssLinkState.WAITING) else logging.WARNING
            log.log(level, "GNSS link %s -> %s: %s", self.state.value, state.value, msg)
        self.state, self.status_message = state, msg


def _receiver_time_period_s(fix: GnssFix) -> float:
    """Where the fix's receiver time wraps: a NAV-PVT's iTOW at the end of the GPS week, NMEA's UTC time of
    day at midnight."""
    return WEEK_S if "itow_ms" in fix.extra else DAY_S
