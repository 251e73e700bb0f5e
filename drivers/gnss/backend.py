"""The one interface every GNSS source implements: what the daemon's GNSS task reads, the same way for all.

Like ArduPilot's AP_GPS_Backend (libraries/AP_GPS/GPS_Backend.h: a receiver driver is one class with one
`read()` that the frontend calls), a new receiver is one class deriving from `GnssBackend`:

* `start()` begins delivering (a simulator's writer, a recording's header). A configuration the source
  refuses raises here, so the daemon fails at start with the reason; a device that is merely absent does not:
  it is a DEVICE_ERROR in `health()` and is opened when it appears (the IMU never waits for the GNSS).
* `read()` returns the fixes available now. It never blocks and never raises: a bad byte, message or row is
  counted in `stats()` and logged, never thrown.
* `offer(msg, t_s)` is every MAVLink message from the autopilot, received at `t_s`; a backend that does not
  take its fixes from MAVLink ignores it (the default).
* `fileno()` is a descriptor that becomes readable when `read()` may have fixes (-1: none; the caller polls).
* `health()` is the link as seen from the source (not the fix quality), `stats()` its counters by group, for
  the daemon's --stats-file, `close()` releases everything.

Time base: each fix's `t_s` is its time of validity on the clock the backend was given at construction (the
IMU samples' clock, or a recording's time base); a backend never takes the time from another object.
"""

from __future__ import annotations

import abc
import enum
from dataclasses import dataclass

from ahrsd.core.gnss import GnssFix


class GnssLinkState(enum.Enum):
    """What the link to the source is doing, as seen from its bytes or messages (not from the fix quality)."""

    WAITING = "waiting"              # started, nothing yet (within the timeouts)
    OK = "ok"                        # fixes arrive
    SILENT = "silent"                # no bytes at all
    GARBAGE = "garbage"              # bytes but no valid frame: baud mismatch, wrong wiring, noise
    WRONG_PROTOCOL = "wrong_protocol"  # valid frames, but none this source can use
    DEVICE_ERROR = "device_error"    # the device or file cannot be read (absent, unplugged, unreadable)

    @property
    def usable(self) -> bool:
        """The link itself is not in trouble (a fix may still be missing)."""
        return self in (GnssLinkState.OK, GnssLinkState.WAITING)


@dataclass(frozen=True)
class GnssHealth:
    state: GnssLinkState
    message: str = ""                # for the log: what is wrong and what to check


class GnssBackend(abc.ABC):
    """One GNSS source. See the module docstring for the contract of each method."""

    description: str = "GNSS"        # for the log: "receiver on /dev/ttyAMA0 at 115200 baud (ubx)"

    def start(self) -> None:
        """Begin delivering; raises on a configuration the source refuses (missing recording, bad header)."""

    @abc.abstractmethod
    def read(self) -> list[GnssFix]:
        """The fixes available now, oldest first; never blocks, never raises."""

    def offer(self, msg, t_s: float) -> None:
        """A MAVLink message from the autopilot, received at `t_s` on the samples' clock."""

    def fileno(self) -> int:
        """A descriptor that becomes readable when `read()` may return fixes; -1 when there is none."""
        return -1

    @abc.abstractmethod
    def health(self) -> GnssHealth:
        """The link state now (cheap; call it as often as needed)."""

    @abc.abstractmethod
    def stats(self) -> dict[str, dict]:
        """Counters by group name ("serial", "mavlink", "recording", ...), merged into the daemon's stats."""

    def close(self) -> None:
        """Release the device, file or thread."""
