"""The one path for every calibration change (mag-cal accept/autosave, fixed yaw, gyro calibration): persist,
swap between two samples, and bring the published heading to the new one without a step the autopilot rejects;
and the heading reset the autopilot is told about (VISION_POSITION_ESTIMATE.reset_counter)."""

from __future__ import annotations

import logging

from ahrsd.calibration.store import CalibrationStore
from ahrsd.daemon.mag_trust import calibration_heading_sigma_rad

log = logging.getLogger(__name__)


class CalibrationSwap:
    """Service part: `apply_calibration`, `signal_heading_reset` (uses pipeline, heading_slew, state_dir)."""

    @property
    def calibration(self):
        return self.pipeline.calibration

    def apply_calibration(self, cal, *, save: bool = True, reason: str = "") -> None:
        """Persist (when `save`; an error propagates and the previous calibration stays in force and on disk)
        and swap the calibration atomically between two samples. The one path for every calibration change
        (mag-cal accept/autosave, fixed yaw, gyro calibration).

        The estimator re-learns its field reference (`relearn_field_reference`: it would otherwise reject
        the corrected field as a disturbance and jump later), and the yaw in VISION_POSITION_ESTIMATE moves to
        the new heading at no more than `[outputs] heading_slew_deg_s` (EKF3 rejects a yaw step beyond its
        3σ gate in flight). reset_counter is left alone unless `reset_counter_on_calibration`: ArduPilot
        reads a new value as a position reset, PX4 EKF2 as a yaw reset (docs/daemon.md "reset_counter").
        """
        if save:
            CalibrationStore(self.state_dir).save(cal)
        self.pipeline.calibration = cal
        self._log_calibration(cal)               # the sample log's next file names it (daemon.vehicle_log)
        relearn = getattr(self.pipeline.estimator, "relearn_field_reference", None)
        if relearn is not None:
            relearn()
        self._calibration_trust_changed(cal)
        if self.config.outputs.reset_counter_on_calibration:
            self.signal_heading_reset()
        else:
            self.heading_slew.start_transition()
        log.info("calibration applied%s", f" ({reason})" if reason else "")

    def _calibration_trust_changed(self, cal) -> None:
        """The new calibration's predicted heading error to ins and the heading status; the iron learned on
        the old magnetometer calibration is reset (daemon.learned_iron)."""
        sigma = calibration_heading_sigma_rad(cal)
        set_sigma = getattr(self.pipeline.estimator, "set_mag_calibration_sigma", None)
        if set_sigma is not None:
            set_sigma(sigma)
        if self.heading_status is not None:
            self.heading_status.set_calibration_sigma(sigma)
        if self.learned_iron is not None:
            self.learned_iron.calibration_changed()

    def signal_heading_reset(self) -> None:
        """A heading discontinuity the autopilot is told about (estimator re-initialised, mounting or
        declination changed): VISION_POSITION_ESTIMATE.reset_counter + 1, and the yaw is sent as it is (any
        calibration slew still running ends: the reset replaces it)."""
        self.reset_counter += 1
        self.heading_slew.active = False

