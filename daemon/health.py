"""Health of the sensor chain as MAVLink sees it: HEARTBEAT.system_status and SYS_STATUS sensor bits.

States (MAV_STATE, anchor §7): BOOT until the first estimate; STANDBY while the estimator initialises;
ACTIVE when attitude and heading are good; CALIBRATING while a calibration holds the daemon; CRITICAL when the
sensor stopped delivering samples or delivers invalid ones.
"""

from __future__ import annotations

from dataclasses import dataclass

from ahrsd.daemon import messages as msgs
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.drivers.sample import SampleFlags
from ahrsd.estimator.base import EstimateFlags

STATE_NAMES = {
    mavlink.MAV_STATE_BOOT: "BOOT", mavlink.MAV_STATE_STANDBY: "STANDBY", mavlink.MAV_STATE_ACTIVE: "ACTIVE",
    mavlink.MAV_STATE_CALIBRATING: "CALIBRATING", mavlink.MAV_STATE_CRITICAL: "CRITICAL",
    mavlink.MAV_STATE_POWEROFF: "POWEROFF",
}
PRESENT = msgs.SENSOR_GYRO | msgs.SENSOR_ACCEL | msgs.SENSOR_MAG | msgs.SENSOR_AHRS
GYRO_BAD = SampleFlags.GYRO_INVALID | SampleFlags.GYRO_SATURATED
ACCEL_BAD = SampleFlags.ACCEL_INVALID | SampleFlags.ACCEL_SATURATED
MAG_BAD = SampleFlags.MAG_INVALID | SampleFlags.MAG_SATURATED


@dataclass
class Health:
    stale_timeout_s: float
    last_sample_time: float | None = None     # monotonic time of the last processed sample
    last_sample_flags: SampleFlags = SampleFlags.NONE
    last_estimate_flags: EstimateFlags | None = None
    sensor_error: str = ""                    # why the sensor is failed ("" = no bus error)
    calibrating: str = ""                     # what is calibrating ("" = nothing)

    def samples_flowing(self, now: float) -> bool:
        return self.last_sample_time is not None and now - self.last_sample_time <= self.stale_timeout_s

    def sensor_ok(self, now: float) -> bool:
        invalid = SampleFlags.GYRO_INVALID | SampleFlags.ACCEL_INVALID
        return self.samples_flowing(now) and not self.sensor_error and not self.last_sample_flags & invalid

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
        if self.last_estimate_flags & EstimateFlags.INITIALISING:
            return mavlink.MAV_STATE_STANDBY
        return mavlink.MAV_STATE_ACTIVE

    def sensor_bits(self, now: float) -> tuple[int, int, int]:
        """(present, enabled, health) MAV_SYS_STATUS_SENSOR bitmaps."""
        healthy = 0
        if self.samples_flowing(now) and not self.sensor_error:
            f = self.last_sample_flags
            if not f & GYRO_BAD:
                healthy |= msgs.SENSOR_GYRO
            if not f & ACCEL_BAD:
                healthy |= msgs.SENSOR_ACCEL
            ef = self.last_estimate_flags or EstimateFlags.NONE
            if not f & MAG_BAD and not ef & EstimateFlags.MAG_UNAVAILABLE:
                healthy |= msgs.SENSOR_MAG
            # mag-less (gyro-only heading, uncertainty growing): the heading still flows with its honest
            # variance, but the AHRS is not healthy (docs/reliability.md)
            if self.heading_trusted(now) and not ef & EstimateFlags.MAG_UNAVAILABLE:
                healthy |= msgs.SENSOR_AHRS
        return PRESENT, PRESENT, healthy
