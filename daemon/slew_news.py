"""What the operator is told while the heading sent to the autopilot is brought to a new one (daemon.heading_slew):
a STATUSTEXT when a transition starts (why, and how: slewed at a rate or held for a re-alignment) and when it ends
(the largest offset and how it ended), and the status line's "slew ±X°" (what is left) meanwhile. During the
transition the VPE yaw is off the estimator's heading by that offset, and its variance says so
(HeadingSlew.published_sigma_rad)."""

from __future__ import annotations

import math
from typing import Callable

from ahrsd.daemon.mavlink_io import mavlink


# a transition is news once the published yaw is this far off the estimator's (as a restart difference below
# daemon.restart_heading.RESTART_STEP_DEG is sent as it is); a calibration that hardly moves the heading says nothing
ANNOUNCE_OFFSET_RAD = math.radians(1.0)


class SlewNews:
    """`after_update(slew)` after every published heading; `statustext(severity, text)` sends one STATUSTEXT
    (each text fits one message: 50 ASCII characters, "°" spelled " deg")."""

    def __init__(self, statustext: Callable[[int, str], None]):
        self.statustext = statustext
        self.announced = False
        self.largest_rad = 0.0

    def after_update(self, slew) -> None:
        if slew.active:
            self.largest_rad = max(self.largest_rad, abs(slew.remaining_rad))
            if not self.announced and self.largest_rad >= ANNOUNCE_OFFSET_RAD:
                self.announced = True
                how = "yaw held to realign" if slew.hold_until_s is not None \
                    else f"slewing ≤{slew.current_rate_deg_s:g}°/s"
                self.statustext(mavlink.MAV_SEVERITY_INFO, f"ahrsd: {slew.reason}, {how}")
            return
        if self.announced:
            self.statustext(mavlink.MAV_SEVERITY_INFO, f"ahrsd: yaw change {math.degrees(self.largest_rad):.1f}° "
                                                       f"{slew.ended_why or 'ended'}")
        self.announced, self.largest_rad = False, 0.0

    @staticmethod
    def status_text(slew) -> str:
        """For the status line: "slew +12.3°" (what is left to bring in) while a transition runs, else ""."""
        return f"slew {math.degrees(slew.remaining_rad):+.1f}°" if slew.active else ""
