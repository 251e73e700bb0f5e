"""What a failed read of a per-sample source means: one policy for every reader (the daemon's sample reader,
the reader thread of drivers.threaded_source, `ahrsd record`), so a recording and the running daemon call the
same sensor failed.

* A corrupt frame (`FrameError`: garbage, a short read, implausible values) is counted by the driver and the
  next sample is read one period later: one bad frame is interference, not a failure. FRAME_ERRORS_FOR_FAILURE
  in a row (100 periods, an eighth of a second at the chip's default 819.2 SPS) are no longer interference: the
  sensor has failed.
* Any other read error (`BusError`, an `OSError` from the device node) means the sensor has failed at once;
  the next attempt comes RETRY_AFTER_FAILURE_S later (a bus that is gone is not polled at the sample rate).

What a reader does with a failed sensor is its own: the daemon reports it (STATUSTEXT, health bits) and keeps
retrying, since the source reconnects; `ahrsd record` stops, because a recording with a hole the size of an
outage is not what was asked for.
"""

from __future__ import annotations

from dataclasses import dataclass

from ahrsd.drivers.errors import FrameError

FRAME_ERRORS_FOR_FAILURE = 100
RETRY_AFTER_FAILURE_S = 0.2


@dataclass(frozen=True)
class ReadVerdict:
    failed: bool                  # the sensor counts as failed now
    retry_after_s: float | None   # when to read again: None = at the next sample time


class ReadFailures:
    """The consecutive-failure count of one reader. Call `read_ok()` after every read that did not raise
    (a sample, or none ready yet) and `read_failed(exc)` after one that raised."""

    def __init__(self, frame_errors_for_failure: int = FRAME_ERRORS_FOR_FAILURE):
        if frame_errors_for_failure < 1:
            raise ValueError(f"frame_errors_for_failure must be ≥ 1, not {frame_errors_for_failure}")
        self.frame_errors_for_failure = frame_errors_for_failure
        self.consecutive_frame_errors = 0

    def read_ok(self) -> None:
        self.consecutive_frame_errors = 0

    def read_failed(self, exc: Exception) -> ReadVerdict:
        if isinstance(exc, FrameError):
            self.consecutive_frame_errors += 1
            return ReadVerdict(self.consecutive_frame_errors >= self.frame_errors_for_failure, None)
        return ReadVerdict(True, RETRY_AFTER_FAILURE_S)
