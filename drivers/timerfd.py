"""A CLOCK_MONOTONIC timerfd (Linux `timerfd_create(2)`, through ctypes: Python 3.11 has no os.timerfd_create) armed
at absolute times: a thread blocked in `wait()` (a read of the descriptor, without the GIL) wakes when the timer
expires, and another thread moves the expiry with `arm(t)` without waking it. The IIO reader thread waits on one
that the daemon's event loop arms for its next output (drivers.threaded_source); daemon.timerfd's DeadlineTimer
serves the event loop's own deadlines with one."""

from __future__ import annotations

import ctypes
import ctypes.util
import os

CLOCK_MONOTONIC = 1
TFD_NONBLOCK = os.O_NONBLOCK
TFD_CLOEXEC = os.O_CLOEXEC
TFD_TIMER_ABSTIME = 1


class Timespec(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long)]


class Itimerspec(ctypes.Structure):
    _fields_ = [("it_interval", Timespec), ("it_value", Timespec)]


def libc(hold_gil: bool = False):
    """The C library with timerfd_create / timerfd_settime typed, or None where it has none. hold_gil: its calls keep
    the GIL (ctypes.PyDLL; CDLL releases it around each call, so a thread waiting for the GIL takes it, and the
    caller waits to get it back: a context switch for a system call of a microsecond)."""
    try:
        lib = (ctypes.PyDLL if hold_gil else ctypes.CDLL)(ctypes.util.find_library("c") or "libc.so.6",
                                                           use_errno=True)
        lib.timerfd_create.argtypes = (ctypes.c_int, ctypes.c_int)
        lib.timerfd_settime.argtypes = (ctypes.c_int, ctypes.c_int, ctypes.POINTER(Itimerspec),
                                        ctypes.POINTER(Itimerspec))
        return lib
    except (OSError, AttributeError):
        return None


def set_expiry(lib, fd: int, spec: Itimerspec, t: float) -> int:
    """Arm timerfd `fd` to expire once at CLOCK_MONOTONIC time `t` (s; a past time expires at once): 0, or -1
    with errno set."""
    sec = int(t)
    spec.it_value.tv_sec = sec
    spec.it_value.tv_nsec = max(1, int((t - sec) * 1e9))     # 0/0 would disarm
    return lib.timerfd_settime(fd, TFD_TIMER_ABSTIME, ctypes.byref(spec), None)


class TimerFd:
    """A blocking one-shot CLOCK_MONOTONIC timer: `arm(t)` from any thread, `wait()` in the waiting one."""

    def __init__(self):
        lib = libc(hold_gil=True)      # armed from the event loop: it keeps the GIL through the call
        fd = lib.timerfd_create(CLOCK_MONOTONIC, TFD_CLOEXEC) if lib is not None else -1
        if fd < 0:
            raise OSError(ctypes.get_errno(), "timerfd_create failed")
        self._lib, self.fd = lib, fd

    def arm(self, t: float) -> None:
        # a spec of its own per call: two threads may arm at once
        if set_expiry(self._lib, self.fd, Itimerspec(), t) != 0:
            raise OSError(ctypes.get_errno(), "timerfd_settime failed")

    def wait(self) -> None:
        """Block until the timer expires (at once if it did since the last wait)."""
        os.read(self.fd, 8)

    def close(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1
