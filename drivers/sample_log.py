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

from pathlib import Path

from .recording import SAMPLE_COLUMNS, RecordingWriter
from .rotating_log import RotatingLog

SAMPLE_LOG_PREFIX = "imu"
SAMPLE_LOG_SUFFIX = ".csv.gz"
SAMPLE_LOG_FORMAT = "ahrsd-recording"


class SampleLog(RotatingLog):
    prefix = SAMPLE_LOG_PREFIX
    suffix = SAMPLE_LOG_SUFFIX
    format_name = SAMPLE_LOG_FORMAT

    def _open(self, path: Path) -> RecordingWriter:
        # RecordingWriter flushes its own buffer only every flush_rows rows; the base class flushes on time
        writer = RecordingWriter(path, extra_columns=SAMPLE_COLUMNS, flush_rows=1 << 62)
        writer.flush()   # the header on disk at once: only a crash within this call leaves a file without one
        return writer

    def _write(self, writer: RecordingWriter, sample) -> None:
        writer.write(sample)

    def _entry_time_s(self, sample) -> float:
        return sample.t_s
