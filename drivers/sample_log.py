"""The on-vehicle sample log: every ImuSample the service reads, as recordings (`.csv.gz`, the public recording
format of drivers/recording.py with the ImuSample's own columns), rotating and capped (drivers/rotating_log.py).

    log = SampleLog("/var/lib/ahrsd/logs", metadata={"calibrated": True, "calibration": {...}})
    log.put(sample)          # from the reader: never blocks; dropped and counted when the writer falls behind
    log.set_metadata(calibration={...})   # after a calibration swap: a new file starts
    log.close()

Each file reads with `read_recording(path, strict=False)` / `iter_samples` as it is, including one cut by a
crash (up to its last complete line: the writer flushes the gzip stream every `flush_interval_s`). Its sidecar
`<file>.json` says which calibration was in force (`calibrated`, `calibration`) and maps sample times to UTC
(`unix_minus_t_s`).
"""

from __future__ import annotations

import time
from pathlib import Path

from .recording import SAMPLE_COLUMNS, RecordingWriter
from .rotating_log import LogLimits, RotatingLog

SAMPLE_LOG_PREFIX = "imu"
SAMPLE_LOG_SUFFIX = ".csv.gz"
SAMPLE_LOG_FORMAT = "ahrsd-recording"


def monotonic_to_unix_s() -> float:
    """Unix time minus the monotonic clock: the service's sample times (t_s) are on the monotonic clock."""
    return time.time() - time.monotonic()


class SampleLog(RotatingLog):
    """Metadata the service gives: `calibrated` (bool: were the samples put calibrated?) and `calibration` (a
    dict naming the calibration in force: checksum, method, date, path)."""

    prefix = SAMPLE_LOG_PREFIX
    suffix = SAMPLE_LOG_SUFFIX
    format_name = SAMPLE_LOG_FORMAT

    def __init__(self, directory, limits: LogLimits = LogLimits(), metadata: dict | None = None, clock=time.time,
                 unix_minus_t=monotonic_to_unix_s):
        super().__init__(directory, limits, metadata, clock, unix_minus_t)

    def _open(self, path: Path) -> RecordingWriter:
        # RecordingWriter flushes its own buffer only every flush_rows rows; the base class flushes on time
        writer = RecordingWriter(path, extra_columns=SAMPLE_COLUMNS, flush_rows=1 << 62)
        writer.flush()   # the header on disk at once: only a crash within this call leaves a file without one
        return writer

    def _write(self, writer: RecordingWriter, sample) -> None:
        writer.write(sample)

    def _entry_time_s(self, sample) -> float:
        return sample.t_s
