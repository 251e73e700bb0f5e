"""The daemon's on-vehicle logs ([log], docs/logging.md): every raw driver sample into a SampleLog (.csv.gz),
every GNSS fix the source delivered, accepted or rejected (with the validator's reason), into a GnssLog
(.gnss.csv.gz, beside the samples whenever they are logged and a GNSS source is configured) and every MAVLink
frame in and out into a TlogLog (.tlog), all behind the bounded queues of drivers/rotating_log.py, so the
reader's cost is one deque append per sample and nothing on it ever waits for the disk. A full disk or a read-only directory stops a log with one warning; the daemon keeps running, and
the counters (written, dropped, failure) go into the stats file (`VehicleLogs.counters`).
"""

from __future__ import annotations

import logging

from ahrsd.calibration.store import checksum
from ahrsd.drivers.gnss.log import GnssLog
from ahrsd.drivers.gnss.validation import GnssRejection
from ahrsd.drivers.rotating_log import LogLimits
from ahrsd.drivers.sample_log import SampleLog
from ahrsd.drivers.tlog import TlogLog

log = logging.getLogger(__name__)

MB = 1024 * 1024
TLOG_SHARE = 0.25   # of max_total_mb when both logs are on (the sample log is the larger: docs/logging.md)
GNSS_SHARE = 0.02   # of the samples' share for their GNSS fixes (10 fixes/s are ~1 % of 819.2 samples/s)


def calibration_summary(cal) -> dict:
    """What the sidecar says about the calibration in force: its checksum (as calibration/store.py computes
    it for the file), the methods and the latest date of the per-sensor sections."""
    sections = [cal.metadata[s] for s in ("gyro", "accel", "mag") if isinstance(cal.metadata.get(s), dict)]
    methods = [f"{s}:{cal.metadata[s].get('method', '?')}" for s in ("gyro", "accel", "mag")
               if isinstance(cal.metadata.get(s), dict)]
    dates = sorted(str(sec["date"]) for sec in sections if sec.get("date"))
    return {"checksum": checksum(cal.to_dict()), "identity": cal.is_identity,
            "method": ", ".join(methods) or str(cal.metadata.get("method", "")), "date": dates[-1] if dates else ""}


class VehicleLogs:
    """The on-vehicle logs of one daemon run (`[log]` config). `start(calibration, endpoints)` after the pipeline
    and the endpoints exist; `log_calibration` after a calibration swap; `log_gnss_fix` every fix (from
    daemon.gnss_task); `close(endpoints)` at shutdown; `counters()` for the stats file. `put_sample` is the
    reader's one call per raw sample (None: not logging samples)."""

    def __init__(self, cfg, *, state_dir, environ, gnss_source: str):
        self.cfg = cfg
        self.state_dir = state_dir
        self.environ = environ
        self.gnss_source = gnss_source
        self.sample_log: SampleLog | None = None
        self.gnss_log: GnssLog | None = None
        self.mavlink_log: TlogLog | None = None
        self.put_sample = None

    def start(self, calibration, endpoints) -> None:
        cfg = self.cfg
        if not cfg.is_enabled(self.environ) or not (cfg.samples or cfg.tlog):
            return
        directory = cfg.resolve_dir(self.state_dir)
        total_bytes = int(cfg.max_total_mb * MB)
        tlog_bytes = int(total_bytes * TLOG_SHARE) if cfg.samples else total_bytes

        def limits(cap_bytes: int) -> LogLimits:
            return LogLimits(max_file_bytes=int(cfg.rotate_mb * MB), max_file_age_s=cfg.rotate_s,
                             max_total_bytes=max(cap_bytes, int(cfg.rotate_mb * MB)))

        if cfg.samples:
            # raw driver samples: replay and calibrate re-apply whatever calibration they are given; the
            # sidecar still names the calibration the daemon had in force
            samples_bytes = total_bytes - tlog_bytes if cfg.tlog else total_bytes
            gnss_bytes = int(samples_bytes * GNSS_SHARE) if self.gnss_source != "none" else 0
            self.sample_log = SampleLog(directory, limits(samples_bytes - gnss_bytes),
                                        metadata={"calibrated": False,
                                                  "calibration": calibration_summary(calibration)})
            self.put_sample = self.sample_log.put
            if gnss_bytes:
                self.gnss_log = GnssLog(directory, limits(gnss_bytes), metadata={"gnss_source": self.gnss_source})
        if cfg.tlog:
            self.mavlink_log = TlogLog(directory, limits(tlog_bytes))
            for ep in endpoints:
                ep.traffic_log = self.mavlink_log.put
        log.info("logging %s to %s", ", ".join(n for n, on in (("raw samples", cfg.samples),
                                                                 ("GNSS fixes", self.gnss_log is not None),
                                                                 ("MAVLink traffic", cfg.tlog)) if on), directory)

    def log_calibration(self, cal) -> None:
        if self.sample_log is not None:
            self.sample_log.set_metadata(calibration=calibration_summary(cal))

    def log_gnss_fix(self, fix, rejection) -> None:
        """One fix as the GNSS source delivered it, with the validator's verdict (None: accepted). A malformed
        object (not a fix the format can hold) is not logged: the validator has counted it."""
        if self.gnss_log is not None and rejection is not GnssRejection.MALFORMED:
            self.gnss_log.put((fix, rejection))

    def close(self, endpoints) -> None:
        self.put_sample = None
        for ep in endpoints:
            ep.traffic_log = None
        for kind in (self.sample_log, self.gnss_log, self.mavlink_log):
            if kind is not None:
                kind.close()

    def counters(self) -> dict:
        """Per log: written, dropped (queue full or stopped), failure (why it stopped, None while OK), files."""
        return {name: kind.counters for name, kind in (("samples", self.sample_log), ("gnss", self.gnss_log),
                                                       ("tlog", self.mavlink_log)) if kind is not None}
