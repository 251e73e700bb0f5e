"""The heading the autopilot is sent and its discontinuities: VISION_POSITION_ESTIMATE.reset_counter and the
slew that brings the published yaw to a new calibration's heading (daemon.heading_slew)."""

from __future__ import annotations

from ahrsd.core.angles import yaw_rate_ned_rad_s
from ahrsd.daemon.heading_slew import HeadingSlew
from ahrsd.daemon.restart_heading import RestartHeading


class HeadingResets:
    """Owns `reset_counter` and the `slew`. `signal()` is a heading discontinuity the autopilot is told about
    (estimator re-initialised, mounting or declination changed): reset_counter + 1, and the yaw is sent as it
    is (a calibration slew still running ends: the reset replaces it)."""

    def __init__(self, slew: HeadingSlew, reset_counter: int = 0):
        self.slew = slew
        self.reset_counter = reset_counter
        self.restart: RestartHeading | None = None   # the restart rule, once loaded (daemon.restart_heading)

    def signal(self) -> None:
        self.reset_counter += 1
        self.slew.active = False

    def autopilot_yaw(self, est) -> tuple[float, int]:
        """The yaw VISION_POSITION_ESTIMATE carries for `est` (slewed after a calibration change or a restart
        with another heading) and the reset_counter."""
        restart = self.restart          # a restart with another heading: daemon.restart_heading
        if restart is not None:
            restart.before_publish(est.t_s, est.heading_true_rad)
        yaw = self.slew.update(est.t_s, est.heading_true_rad,
                               yaw_rate_ned_rad_s(est.rate_body_rad_s, est.roll_rad, est.pitch_rad))
        if restart is not None:
            restart.after_publish(yaw, self.reset_counter)
        return yaw, self.reset_counter
