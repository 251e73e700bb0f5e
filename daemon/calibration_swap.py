"""The one path for every calibration change (mag-cal accept/autosave, fixed yaw, gyro calibration): persist,
swap between two samples, and bring the published heading to the new one without a step the autopilot rejects."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Callable

from ahrsd.calibration.store import CalibrationStore
from ahrsd.daemon.calibration_heading_change import calibration_heading_change_rad
from ahrsd.daemon.heading_resets import HeadingResets
from ahrsd.daemon.pipeline import Pipeline

log = logging.getLogger(__name__)


class CalibrationSwap:
    """`apply(cal)`: persist in `state_dir`, swap in `pipeline`, tell `heading` (a reset or a slew), and
    `on_applied(cal)` (the vehicle log names the calibration in force)."""

    def __init__(self, pipeline: Pipeline, state_dir: Path, heading: HeadingResets, *,
                 reset_counter_on_calibration: bool, on_applied: Callable[[object], None] = lambda cal: None):
        self.pipeline = pipeline
        self.state_dir = state_dir
        self.heading = heading
        self.reset_counter_on_calibration = reset_counter_on_calibration
        self.on_applied = on_applied

    def apply(self, cal, *, save: bool = True, reason: str = "") -> None:
        """Persist (when `save`; an error propagates and the previous calibration stays in force and on disk)
        and swap the calibration atomically between two samples.

        The estimator re-learns its field reference (`relearn_field_reference`: it would otherwise reject
        the corrected field as a disturbance and jump later) and widens its yaw variance to how far the new
        calibration's heading of the latest sample is from its own (it may be off by that much now), and the
        yaw in VISION_POSITION_ESTIMATE moves to the new heading at no more than `[outputs] heading_slew_deg_s`
        (EKF3 rejects a yaw step beyond its 3σ gate in flight). reset_counter is left alone unless `reset_counter_on_calibration`: ArduPilot
        reads a new value as a position reset, PX4 EKF2 as a yaw reset (docs/daemon.md "reset_counter").
        """
        if save:
            CalibrationStore(self.state_dir).save(cal)
        change_rad = self._heading_change_rad(cal)
        self.pipeline.calibration = cal
        self.on_applied(cal)
        self.pipeline.estimator.relearn_field_reference(change_rad)
        if self.reset_counter_on_calibration:
            self.heading.signal()
        else:
            self.heading.slew.start_transition()
        log.info("calibration applied%s", f" ({reason})" if reason else "")

    def _heading_change_rad(self, cal) -> float:
        """How far `cal` moves the estimator's heading: its heading of the latest sample minus the estimator's
        (daemon.calibration_heading_change); NaN before the first estimate."""
        p = self.pipeline
        est, sample = p.last_estimate, p.last_raw_sample
        if est is None or sample is None:
            return float("nan")
        return calibration_heading_change_rad(p.calibration, cal, sample.mag_ut, p.mounting, est.roll_rad,
                                              est.pitch_rad, est.yaw_rad)
