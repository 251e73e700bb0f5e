"""The on-vehicle GNSS log: every fix the GNSS source delivered, accepted or rejected by the validator, as GNSS
recordings (`.gnss.csv.gz`, the format of drivers/gnss/recording.py that `--gnss-replay` reads), rotating and
capped like the sample log beside it (drivers/rotating_log.py).

    log = GnssLog("/var/lib/ahrsd/logs")
    log.put((fix, rejection))    # rejection: the validator's GnssRejection, None when accepted
    log.close()

Two extra columns: `receiver_time_s` (the receiver's own clock, which the validator checks; nan when the
source gives none) and `rejection`, the validator's verdict as a number (REJECTION_CODES: 0 accepted, else
the reason; the sidecar lists them). A replay of the file re-judges every fix with the same validator, so
the rejected ones are rejected again, as they were live. Fix times (t_s) are on the samples' clock; the
sidecar's `unix_minus_t_s` maps them to UTC as the sample log's does.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

from .recording import GnssRecordingWriter
from .validation import GnssRejection
from ..rotating_log import LogLimits, RotatingLog
from ..sample_log import monotonic_to_unix_s

GNSS_LOG_PREFIX = "gnss"
GNSS_LOG_SUFFIX = ".gnss.csv.gz"
GNSS_LOG_FORMAT = "ahrsd-gnss-recording"
GNSS_LOG_EXTRA_COLUMNS = ("receiver_time_s", "rejection")
REJECTION_CODES: dict[str, int] = {"accepted": 0, **{r.value: k for k, r in enumerate(GnssRejection, start=1)}}


def rejection_code(rejection: GnssRejection | None) -> int:
    return 0 if rejection is None else REJECTION_CODES[GnssRejection(rejection).value]


def rejection_name(code: float) -> str:
    """The verdict a `rejection` cell holds ("accepted", "time_backwards", ...; "unknown" for other numbers)."""
    return next((name for name, k in REJECTION_CODES.items() if k == code), "unknown")


def with_rejection(fix, rejection: GnssRejection | None):
    """The fix with its verdict in `extra["rejection"]`, as the log's writer takes it."""
    return dataclasses.replace(fix, extra={**fix.extra, "rejection": float(rejection_code(rejection))})


class GnssLog(RotatingLog):
    prefix = GNSS_LOG_PREFIX
    suffix = GNSS_LOG_SUFFIX
    format_name = GNSS_LOG_FORMAT

    def __init__(self, directory, limits: LogLimits = LogLimits(), metadata: dict | None = None, clock=time.time,
                 unix_minus_t=monotonic_to_unix_s):
        super().__init__(directory, limits, {"rejection_codes": REJECTION_CODES, **(metadata or {})}, clock,
                         unix_minus_t)

    def _open(self, path: Path) -> GnssRecordingWriter:
        writer = GnssRecordingWriter(path, extra_columns=GNSS_LOG_EXTRA_COLUMNS, flush_rows=1 << 62)
        writer.flush()   # the header on disk at once
        return writer

    def _write_block(self, writer: GnssRecordingWriter, entries: list) -> None:
        for fix, rejection in entries:
            writer.write(with_rejection(fix, rejection))

    def _entry_time_s(self, entry) -> float | None:
        t = float(entry[0].t_s)
        return t if math.isfinite(t) else None   # a fix rejected for its time may have none
