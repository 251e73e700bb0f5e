"""The heading the autopilot is sent and its discontinuities: VISION_POSITION_ESTIMATE.reset_counter and the
slew that brings the published yaw to a new calibration's heading (daemon.heading_slew)."""

from __future__ import annotations

from typing import Callable

from ahrsd.core.angles import yaw_rate_ned_rad_s
from ahrsd.daemon.heading_slew import HeadingSlew
from ahrsd.daemon.restart_heading import RestartHeading
from ahrsd.daemon.slew_news import SlewNews


class HeadingResets:
    """Owns `reset_counter` and the `slew`. `signal()` is a heading discontinuity the autopilot is told about
    (estimator re-initialised, mounting or declination changed): reset_counter + 1, and the yaw is sent as it
    is (a calibration slew still running ends: the reset replaces it). `statustext(severity, text)` tells the
    operator when a transition starts and ends (daemon.slew_news)."""

    def __init__(self, slew: HeadingSlew, reset_counter: int = 0,
                 statustext: Callable[[int, str], None] = lambda severity, text: None):
        self.slew = slew
        self.reset_counter = reset_counter
        self.restart: RestartHeading | None = None   # the restart rule, once loaded (daemon.restart_heading)
        self.news = SlewNews(statustext)

    def signal(self) -> None:
        self.reset_counter += 1
        self.slew.stop("sent as a yaw reset")

    def autopilot_yaw(self, est) -> tuple[float, int, float]:
        """The yaw VISION_POSITION_ESTIMATE carries for `est` (slewed after a calibration change or a restart
        with another heading), the reset_counter, and the yaw's 1σ: the estimator's, plus what covers the
        offset of a slewed yaw from the estimator's heading (HeadingSlew.published_sigma_rad)."""
        restart = self.restart          # a restart with another heading: daemon.restart_heading
        if restart is not None:
            restart.before_publish(est.t_s, est.heading_true_rad)
        sigma_rad = float(est.sigma_rpy_rad[2])
        yaw = self.slew.update(est.t_s, est.heading_true_rad,
                               yaw_rate_ned_rad_s(est.rate_body_rad_s, est.roll_rad, est.pitch_rad), sigma_rad)
        if restart is not None:
            restart.after_publish(yaw, self.reset_counter)
        self.news.after_update(self.slew)
        return yaw, self.reset_counter, self.slew.published_sigma_rad(sigma_rad)

    def withheld(self, est) -> None:
        """No VISION_POSITION_ESTIMATE is sent for `est` (heading UNKNOWN or not trusted): a running slew follows
        the vehicle's rotation only, so it resumes from the last yaw sent (HeadingSlew.follow)."""
        self.slew.follow(est.t_s, est.heading_true_rad,
                         yaw_rate_ned_rad_s(est.rate_body_rad_s, est.roll_rad, est.pitch_rad))

    def status_text(self) -> str:
        """For the status line: "slew +12.3°" while a transition runs (daemon.slew_news), else ""."""
        return self.news.status_text(self.slew)
