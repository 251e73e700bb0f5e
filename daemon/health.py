"""Health of the sensor chain as MAVLink sees it: HEARTBEAT.system_status and SYS_STATUS sensor bits.

States (MAV_STATE, minimal.xml): BOOT until the first estimate; STANDBY while the estimator initialises;
ACTIVE when attitude and heading are good (daemon.heading_status: `heading_good`); CALIBRATING while a calibration holds the daemon; CRITICAL when the
sensor stopped delivering samples or delivers invalid ones.
"""

from __future__ import annotations

from dataclasses import dataclass

from ahrsd.daemon import messages as msgs
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.core.sample import SampleFlags
from ahrsd.core.estimate import EstimateFlags

STATE_NAMES = {
    mavlink.MAV_STATE_BOOT: "BOOT", mavlink.MAV_STATE_STANDBY: "STANDBY", mavlink.MAV_STATE_ACTIVE: "ACTIVE",
    mavlink.MAV_STATE_CALIBRATING: "CALIBRATING", mavlink.MAV_STATE_CRITICAL: "CRITICAL",
    mavlink.MAV_STATE_POWEROFF: "POWEROFF",
}
PRESENT = msgs.SENSOR_GYRO | msgs.SENSOR_ACCEL | msgs.SENSOR_MAG | msgs.SENSOR_AHRS
GYRO_BAD = SampleFlags.GYRO_INVALID | SampleFlags.GYRO_SATURATED
ACCEL_BAD = SampleFlags.ACCEL_INVALID | SampleFlags.ACCEL_SATURATED
MAG_BAD = SampleFlags.MAG_INVALID | SampleFlags.MAG_SATURATED
_GYRO_BAD, _ACCEL_BAD, _MAG_BAD = int(GYRO_BAD), int(ACCEL_BAD), int(MAG_BAD)
_ANY_BAD = _GYRO_BAD | _ACCEL_BAD | _MAG_BAD
BAD_PERSIST_S = 0.05    # a sensor is unhealthy once its samples were flagged bad this long (≈ 41 samples)
# housekeeping ticks (10 Hz) without a single look of the reader after which an overdue sample counts as missing
# even without an empty read: the reader itself is stuck. Once a busy event loop frees up, the ticks it owes
# run back to back, the reader's wake among them, so one or two can pass without it.
READER_SILENT_TICKS = 5


@dataclass
class Health:
    stale_timeout_s: float
    last_sample_time: float | None = None     # monotonic time of the last processed sample
    last_estimate_flags: EstimateFlags | None = None
    # the reader's evidence (`empty_read`, `sample_read`): samples are missing only when the reader looked while
    # one was overdue and found none, not merely because the clock moved on while the event loop was busy
    last_empty_read_time: float | None = None  # when the reader last looked and found no sample
    ticks_without_read: int = 0               # housekeeping ticks since the reader last looked
    sensor_error: str = ""                    # why the sensor is failed ("" = no bus error)
    calibrating: str = ""                     # what is calibrating ("" = nothing)
    # from daemon.heading_status: may the heading be called good (else STANDBY), health bits it clears
    heading_good: bool = True
    heading_unhealthy_bits: int = 0
    # when each sensor's samples started being flagged bad (None = the last sample was good); an isolated bad
    # sample (one unverified burst-bug gyro word, which the estimator skips) must not flip the daemon to
    # CRITICAL and cut the heading feed: only a condition lasting BAD_PERSIST_S does (docs/reliability.md)
    _flags: int = 0
    _gyro_bad_since: float | None = None
    _accel_bad_since: float | None = None
    _mag_bad_since: float | None = None

    @property
    def last_sample_flags(self) -> SampleFlags:
        return SampleFlags(self._flags)

    @last_sample_flags.setter
    def last_sample_flags(self, flags) -> None:
        """Set after `last_sample_time` for every processed batch (the per-sample path: plain int tests)."""
        f = self._flags = int(flags)
        if not f & _ANY_BAD and self._gyro_bad_since is None and self._accel_bad_since is None \
                and self._mag_bad_since is None:
            return
        t = self.last_sample_time
        if f & _GYRO_BAD:
            if self._gyro_bad_since is None:
                self._gyro_bad_since = t
        else:
            self._gyro_bad_since = None
        if f & _ACCEL_BAD:
            if self._accel_bad_since is None:
                self._accel_bad_since = t
        else:
            self._accel_bad_since = None
        if f & _MAG_BAD:
            if self._mag_bad_since is None:
                self._mag_bad_since = t
        else:
            self._mag_bad_since = None

    def _bad(self, since: float | None) -> bool:
        return since is not None and self.last_sample_time is not None and \
            self.last_sample_time - since >= BAD_PERSIST_S

    def sample_read(self, now: float) -> None:
        """The reader looked at `now` and processed samples."""
        self.last_sample_time = now
        self.ticks_without_read = 0

    def empty_read(self, now: float) -> None:
        """The reader looked at `now` and found no sample (or only a corrupt frame)."""
        self.last_empty_read_time = now
        self.ticks_without_read = 0

    def housekeeping_tick(self) -> None:
        """One housekeeping tick passed (the health report's job)."""
        self.ticks_without_read += 1

    def samples_flowing(self, now: float) -> bool:
        """A sample within stale_timeout_s of `now`; or, when the last is older, the reader has not seen that
        one is missing: it has not looked since one became overdue (an event loop that was busy, e.g. with
        the first batch of a replay under load, delays the look, not the sensor) and it is not stuck."""
        last = self.last_sample_time
        if last is None:
            return False
        if now - last <= self.stale_timeout_s:
            return True
        looked_overdue = self.last_empty_read_time is not None and \
            self.last_empty_read_time - last >= self.stale_timeout_s
        return not looked_overdue and self.ticks_without_read < READER_SILENT_TICKS

    def sensor_ok(self, now: float) -> bool:
        """Samples flow, no bus error, and gyro and accel have not been invalid (or saturated) for
        BAD_PERSIST_S."""
        return (self.samples_flowing(now) and not self.sensor_error and not self._bad(self._gyro_bad_since)
                and not self._bad(self._accel_bad_since))

    def heading_trusted(self, now: float) -> bool:
        """May the autopilot use our heading? Not while initialising or when the sensor failed."""
        f = self.last_estimate_flags
        return f is not None and not f & EstimateFlags.INITIALISING and self.sensor_ok(now)

    def system_status(self, now: float) -> int:
        if self.last_estimate_flags is None and not self.sensor_error:
            return mavlink.MAV_STATE_BOOT
        if not self.sensor_ok(now):
            return mavlink.MAV_STATE_CRITICAL
        if self.calibrating:
            return mavlink.MAV_STATE_CALIBRATING
        if self.last_estimate_flags & EstimateFlags.INITIALISING or not self.heading_good:
            return mavlink.MAV_STATE_STANDBY
        return mavlink.MAV_STATE_ACTIVE

    def sensor_bits(self, now: float) -> tuple[int, int, int]:
        """(present, enabled, health) MAV_SYS_STATUS_SENSOR bitmaps."""
        healthy = 0
        if self.samples_flowing(now) and not self.sensor_error:
            if not self._bad(self._gyro_bad_since):
                healthy |= msgs.SENSOR_GYRO
            if not self._bad(self._accel_bad_since):
                healthy |= msgs.SENSOR_ACCEL
            ef = self.last_estimate_flags or EstimateFlags.NONE
            if not self._bad(self._mag_bad_since) and not ef & EstimateFlags.MAG_UNAVAILABLE:
                healthy |= msgs.SENSOR_MAG
            # mag-less (gyro-only heading, uncertainty growing): the heading still flows with its honest
            # variance, but the AHRS is not healthy (docs/reliability.md)
            if self.heading_trusted(now) and not ef & EstimateFlags.MAG_UNAVAILABLE:
                healthy |= msgs.SENSOR_AHRS
        return PRESENT, PRESENT, healthy & ~self.heading_unhealthy_bits
