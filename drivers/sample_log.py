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

import gzip
import os
import time
from pathlib import Path

from .recording import BASE_COLUMNS, SAMPLE_COLUMNS
from .rotating_log import LogLimits, RotatingLog

SAMPLE_LOG_PREFIX = "imu"
SAMPLE_LOG_SUFFIX = ".csv.gz"
SAMPLE_LOG_FORMAT = "ahrsd-recording"
# zlib level 4, the knee between the writer's CPU and the bytes for these rows: the default (6) costs more CPU
# for few bytes less, level 1 saves CPU for many more bytes (bench/log_size.py, figures in docs/logging.md)
GZIP_LEVEL = 4
SAMPLE_LOG_COLUMNS = BASE_COLUMNS + SAMPLE_COLUMNS


class _ReprCache(dict):
    """repr(value) of the sensor values, remembered: a chip's readings are its LSB times a scale, so a few
    thousand distinct values recur for hours, and repr (the shortest text that reads back to the same double,
    hence bit-exact) is most of the writer's time. ±0.0 (equal as keys, different texts) and nan are never
    stored; past MAX_ENTRIES (a few MB) new values are formatted without being kept."""

    MAX_ENTRIES = 32768

    def __missing__(self, value: float) -> str:
        text = repr(value)
        if value == value and value != 0.0 and len(self) < self.MAX_ENTRIES:
            self[value] = text
        return text


_repr_of = _ReprCache().__getitem__


def monotonic_to_unix_s() -> float:
    """Unix time minus the monotonic clock: the service's sample times (t_s) are on the monotonic clock."""
    return time.time() - time.monotonic()


def format_rows(samples) -> bytes:
    """The CSV rows of `samples` (ImuSample) in SAMPLE_LOG_COLUMNS, as the recording writer writes them."""
    return "".join([repr(float(s.t_s)) + "," + ",".join(map(_repr_of, [*s.gyro_rad_s.tolist(), *s.accel_m_s2.tolist(),
                                                                       *s.mag_ut.tolist(), float(s.temp_c),
                                                                       float(s.supply_v)]))
                    + ",%d,%d,%d\n" % (s.flags, s.diag_stat, s.counter) for s in samples]).encode("ascii")


class SampleFile:
    """One open .csv.gz of the sample log: the header, then blocks of rows. `flush()` is a zlib sync flush to
    the disk's page cache (a cut file reads up to there); `close()` writes the gzip trailer and fsyncs."""

    def __init__(self, raw, gzip_level: int = GZIP_LEVEL):
        self._raw = raw
        self._gz = gzip.GzipFile(fileobj=raw, mode="wb", compresslevel=gzip_level)
        self._gz.write((",".join(SAMPLE_LOG_COLUMNS) + "\n").encode("ascii"))

    @classmethod
    def create(cls, path: Path, gzip_level: int = GZIP_LEVEL) -> "SampleFile":
        return cls(open(path, "xb"), gzip_level)

    def write(self, data: bytes) -> None:
        self._gz.write(data)

    def flush(self) -> None:
        self._gz.flush()          # Z_SYNC_FLUSH, then the raw file's buffer to the kernel

    def close(self) -> None:
        try:
            self._gz.close()      # the trailer; leaves the raw file open
            self._raw.flush()
            os.fsync(self._raw.fileno())
        finally:
            self._raw.close()


class SampleLog(RotatingLog):
    """Metadata the service gives: `calibrated` (bool: were the samples put calibrated?) and `calibration` (a
    dict naming the calibration in force: checksum, method, date, path)."""

    prefix = SAMPLE_LOG_PREFIX
    suffix = SAMPLE_LOG_SUFFIX
    format_name = SAMPLE_LOG_FORMAT
    gzip_level = GZIP_LEVEL

    def __init__(self, directory, limits: LogLimits = LogLimits(), metadata: dict | None = None, clock=time.time,
                 unix_minus_t=monotonic_to_unix_s):
        super().__init__(directory, limits, metadata, clock, unix_minus_t)

    def _open(self, path: Path) -> SampleFile:
        file = SampleFile.create(path, self.gzip_level)
        file.flush()   # the header on disk at once: only a crash within this call leaves a file without one
        return file

    def _write_block(self, file: SampleFile, samples: list) -> None:
        file.write(format_rows(samples))

    def _entry_time_s(self, sample) -> float:
        return sample.t_s
