"""A receiver's byte stream -> GnssFixes, with counters. No I/O: feed it bytes as they arrive.

Framing and parsing are pyubx2's `UBXReader` (which hands NMEA to pynmeagps and RTCM3 to pyrtcm): every
frame is checksum-validated whatever the configured protocol, so a stray sync byte in garbage cannot swallow
a good frame unchecked. The decoder keeps its own buffer and calls the reader on a view of it that stops
(rather than blocks) when a frame is incomplete, so a frame split across reads waits for its end. Any parse
error drops exactly one byte and re-scans, so a truncated frame costs that frame only, never the next one.
Never raises on bad bytes: everything is counted.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

from pyubx2 import ERR_RAISE, GET, NMEA_PROTOCOL, RTCM3_PROTOCOL, UBX_PROTOCOL, VALCKSUM, UBXReader

from .nmea import NmeaEpochAssembler
from .ubx import NAV_PVT_IDENTITY, fix_from_nav_pvt
from ahrsd.core.gnss import GnssFix

log = logging.getLogger(__name__)

PROTOCOLS = ("ubx", "nmea", "auto")
_SYNC_BYTES = (b"\xb5", b"$", b"\xd3")   # first byte of a UBX (0xB5 0x62), NMEA ('$') or RTCM3 (0xD3) frame
MAX_FRAME_BYTES = 4096          # longer "frames" are a false sync in garbage (UBX lengths are 16-bit)
MAX_NMEA_BYTES = 512            # NMEA 0183 allows 82 characters; proprietary sentences are longer


class _NeedMore(Exception):
    """The buffered bytes end inside a frame."""


class _FrameTooLong(Exception):
    """A sync byte whose frame would exceed MAX_FRAME_BYTES / MAX_NMEA_BYTES: not a real frame."""


class _BufferView:
    """A read(n)/readline() stream over a bytearray that raises _NeedMore instead of returning short."""

    def __init__(self):
        self.buf = bytearray()
        self.pos = 0

    def read(self, n: int) -> bytes:
        end = self.pos + n
        if end > MAX_FRAME_BYTES:
            raise _FrameTooLong
        if end > len(self.buf):
            raise _NeedMore
        data = bytes(self.buf[self.pos:end])
        self.pos = end
        return data

    def readline(self) -> bytes:
        end = self.buf.find(b"\n", self.pos, MAX_NMEA_BYTES)
        if end < 0:
            raise _FrameTooLong if len(self.buf) >= MAX_NMEA_BYTES else _NeedMore
        data = bytes(self.buf[self.pos:end + 1])
        self.pos = end + 1
        return data


@dataclass
class StreamCounters:
    """What the decoder saw. Bytes are counted once, as garbage or as part of a valid frame."""

    bytes_in: int = 0
    frames_valid: int = 0            # checksum-valid frames of any protocol
    frames_ubx: int = 0
    frames_nmea: int = 0
    frames_other: int = 0            # RTCM3 and anything else valid
    frames_ignored: int = 0          # valid frames of a protocol/type not used (e.g. NMEA with protocol "ubx")
    fixes: int = 0                   # GnssFixes produced
    garbage_bytes: int = 0           # bytes outside any valid frame
    frames_rejected: int = 0         # sync found but the frame did not parse (includes checksum failures)
    checksum_failures: int = 0
    conversion_errors: int = 0       # valid frames whose values could not be converted to a fix
    last_error: str = ""

    def as_dict(self) -> dict:
        return dict(self.__dict__)


class GnssStreamDecoder:
    """Decode UBX NAV-PVT and/or NMEA RMC/GGA/VTG(/GSA) fixes from a byte stream.

    protocol: "ubx" (NAV-PVT only), "nmea" (RMC/GGA/VTG epochs only) or "auto" (both; once a NAV-PVT has
    been seen, NMEA epochs are ignored so one receiver sending both does not deliver each epoch twice).
    `feed(data, t_s)` returns the fixes completed by `data`; each is stamped with the `t_s` (the caller's
    arrival time minus the receiver latency) of the chunk that brought the frame's last byte, so a frame
    that waited behind a false sync keeps its own arrival time.
    """

    def __init__(self, protocol: str = "auto", source: str = "serial"):
        if protocol not in PROTOCOLS:
            raise ValueError(f"GNSS protocol must be one of {', '.join(PROTOCOLS)}, not {protocol!r}")
        self.protocol = protocol
        self.source = source
        self.counters = StreamCounters()
        self.seen_nav_pvt = False
        self._view = _BufferView()
        self._chunk_ends: list[list] = []      # [end index in the buffer (exclusive), t_s] per fed chunk
        self._reader = UBXReader(self._view, msgmode=GET, validate=VALCKSUM, quitonerror=ERR_RAISE,
                                 protfilter=NMEA_PROTOCOL | UBX_PROTOCOL | RTCM3_PROTOCOL)
        self._nmea = NmeaEpochAssembler(source=f"{source}:nmea")

    @property
    def buffered_bytes(self) -> int:
        return len(self._view.buf)

    def feed(self, data: bytes, t_s: float) -> list[GnssFix]:
        self.counters.bytes_in += len(data)
        buf = self._view.buf
        buf += data
        if data:
            self._chunk_ends.append([len(buf), float(t_s)])
        fixes: list[GnssFix] = []
        while buf:
            start = _next_sync(buf)
            if start:
                self.counters.garbage_bytes += start
                self._consume(start)
                if not buf:
                    break
            self._view.pos = 0
            try:
                raw, parsed = self._reader.read()
            except _NeedMore:
                break
            except _FrameTooLong:
                self._reject("no frame end within the maximum frame length")
                continue
            except Exception as exc:     # pyubx2/pynmeagps/pyrtcm parse errors: a bad frame, never a crash
                self._reject(str(exc) or type(exc).__name__)
                continue
            if raw is None:              # the reader saw no frame (cannot happen with _NeedMore; be safe)
                break
            arrival_t_s = self._arrival_of(self._view.pos - 1)
            self._consume(self._view.pos)
            try:
                fixes += self._frame(raw, parsed, arrival_t_s)
            except Exception as exc:     # a valid frame with values the conversion cannot use
                self.counters.conversion_errors += 1
                self.counters.last_error = f"{type(exc).__name__}: {exc}"
                log.debug("cannot convert %r: %s", parsed, exc)
        return fixes

    def flush(self) -> list[GnssFix]:
        """End of input: emit a pending NMEA epoch."""
        if self.protocol == "ubx" or (self.protocol == "auto" and self.seen_nav_pvt):
            return []
        try:
            fixes = self._nmea.flush()
        except Exception as exc:         # as in feed(): never raise on what the receiver sent
            self.counters.conversion_errors += 1
            self.counters.last_error = f"{type(exc).__name__}: {exc}"
            return []
        self.counters.fixes += len(fixes)
        return fixes

    # ---------------------------------------------------------------------------------------------- internal
    def _reject(self, reason: str) -> None:
        # Drop the sync byte only: the real next frame may start inside the rejected one.
        c = self.counters
        c.frames_rejected += 1
        c.garbage_bytes += 1
        if "checksum" in reason.lower():
            c.checksum_failures += 1
        c.last_error = reason
        self._consume(1)

    def _consume(self, n: int) -> None:
        del self._view.buf[:n]
        for chunk in self._chunk_ends:
            chunk[0] -= n
        while self._chunk_ends and self._chunk_ends[0][0] <= 0:
            self._chunk_ends.pop(0)

    def _arrival_of(self, index: int) -> float:
        """t_s of the chunk that brought the buffer byte at `index`."""
        return next(t for end, t in self._chunk_ends if end > index)

    def _frame(self, raw: bytes, parsed, t_s: float) -> list[GnssFix]:
        c = self.counters
        c.frames_valid += 1
        kind = type(parsed).__name__
        if kind == "UBXMessage":
            c.frames_ubx += 1
            if parsed.identity == NAV_PVT_IDENTITY and self.protocol in ("ubx", "auto"):
                self.seen_nav_pvt = True
                c.fixes += 1
                return [fix_from_nav_pvt(parsed, t_s, source=f"{self.source}:ubx")]
        elif kind == "NMEAMessage":
            c.frames_nmea += 1
            use_nmea = self.protocol == "nmea" or (self.protocol == "auto" and not self.seen_nav_pvt)
            if use_nmea:
                fixes = self._nmea.add(parsed, t_s)
                c.fixes += len(fixes)
                return fixes
        else:
            c.frames_other += 1
        c.frames_ignored += 1
        return []


def _next_sync(buf: bytearray) -> int:
    """Index of the first possible frame start (len(buf) if none)."""
    positions = [i for i in (buf.find(b) for b in _SYNC_BYTES) if i >= 0]
    return min(positions) if positions else len(buf)


