"""systemd notification protocol (sd_notify(3)) in a few lines of socket code, no dependency.

`Notifier` sends datagrams such as ``READY=1`` or ``WATCHDOG=1`` to the AF_UNIX socket named by
``$NOTIFY_SOCKET`` (a path, or an abstract socket written with a leading ``@``). Without the variable every
call is a no-op, so the daemon runs the same way under systemd, in a terminal and in tests.
"""

from __future__ import annotations

import logging
import os
import socket

log = logging.getLogger(__name__)


def watchdog_interval_s(environ=os.environ) -> float | None:
    """Seconds between WATCHDOG=1 pings (half of $WATCHDOG_USEC, sd_watchdog_enabled(3)), or None.

    $WATCHDOG_PID, when set, must name this process; otherwise the watchdog is meant for someone else.
    """
    usec = environ.get("WATCHDOG_USEC")
    if not usec:
        return None
    pid = environ.get("WATCHDOG_PID")
    if pid and pid.strip() != str(os.getpid()):
        return None
    try:
        value = int(usec)
    except ValueError:
        log.warning("ignoring malformed WATCHDOG_USEC=%r", usec)
        return None
    return value / 2e6 if value > 0 else None


class Notifier:
    """Sends sd_notify messages; never raises (notification failures are logged once and counted)."""

    def __init__(self, environ=os.environ):
        self.address = self._address(environ.get("NOTIFY_SOCKET", ""))
        self.failures = 0
        self._sock: socket.socket | None = None
        if self.address is not None:
            try:
                self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            except OSError as exc:  # pragma: no cover - only without AF_UNIX
                log.warning("cannot create the notify socket: %s", exc)

    @staticmethod
    def _address(path: str) -> str | bytes | None:
        if not path:
            return None
        if path.startswith("@"):
            return b"\0" + path[1:].encode()  # abstract namespace (sd_notify(3))
        if path.startswith("/"):
            return path
        log.warning("ignoring NOTIFY_SOCKET=%r: neither a path nor an abstract '@' socket", path)
        return None

    @property
    def enabled(self) -> bool:
        return self._sock is not None

    def notify(self, *fields: str) -> bool:
        """Send one datagram of newline-separated ``KEY=value`` fields; True if it was sent."""
        if self._sock is None:
            return False
        try:
            self._sock.sendto("\n".join(fields).encode(), self.address)
            return True
        except OSError as exc:
            if self.failures == 0:
                log.warning("sd_notify to %r failed: %s", self.address, exc)
            self.failures += 1
            return False

    def ready(self, status: str = "") -> bool:
        return self.notify("READY=1", *( [f"STATUS={status}"] if status else []))

    def status(self, text: str) -> bool:
        return self.notify(f"STATUS={text}")

    def watchdog(self) -> bool:
        return self.notify("WATCHDOG=1")

    def stopping(self, status: str = "") -> bool:
        return self.notify("STOPPING=1", *([f"STATUS={status}"] if status else []))

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
