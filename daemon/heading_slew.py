"""The output policy that keeps the heading sent to the autopilot from stepping when a new magnetometer
calibration is swapped in."""

from __future__ import annotations

import math
from dataclasses import dataclass

from ahrsd.core.angles import wrap_pi
from ahrsd.estimator.slewed_yaw import YawSlew

# the longest interval between two published headings the slew moves across in one step: ArduPilot needs external
# navigation data at > 3.3 Hz (docs/daemon.md); a longer interval is a gap in what the autopilot received, and the
# first heading after it must not jump by rate × gap
MAX_STEP_INTERVAL_S = 0.3
# a heading last sent longer ago than this is not what the autopilot has: it has long been on its own yaw (its
# gyros, its own yaw sources), so a transition does not slew from it (daemon.restart_heading uses the same age
# for a remembered heading)
MAX_SLEW_FROM_AGE_S = 600.0


@dataclass
class HeadingSlew:
    """Keeps the heading sent to the autopilot from stepping when a new calibration is swapped in.

    ArduPilot EKF3 rejects an external-yaw innovation beyond its gate in flight and then keeps its old yaw
    (libraries/AP_NavEKF3/AP_NavEKF3_MagFusion.cpp, fuseEulerYaw, gate EK3_YAW_I_GATE), so after
    `start_transition()` the published heading follows the vehicle's own rotation (yaw rate from the
    estimator) and moves towards the estimator's new heading at no more than `max_rate_deg_s` (a restart
    with another heading uses its own rate: daemon.restart_heading), by the slew ins's published heading takes
    too (estimator.slewed_yaw.YawSlew: slower while the offset is large, its σ). What is particular here: the
    heading sent is kept (not an offset), the vehicle's rotation comes as a yaw rate, a transition has a start, a
    hold and an end. Outside a transition it passes the heading through unchanged.

    A transition needs a heading the autopilot has: when none was ever sent (a first calibration of a vehicle
    whose heading was unknown: the VPE was withheld) or the last was sent more than MAX_SLEW_FROM_AGE_S ago,
    there is nothing to slew from, and the first heading sent is the estimator's; the transition ends at once
    ("nothing sent before", no STATUSTEXT: daemon.slew_news announces only a transition that moved an offset).

    While a transition runs the published heading is off the estimator's by `remaining_rad`, a known error the
    VPE's yaw variance must cover (`published_sigma_rad`).

    While no heading is sent during a transition (the heading UNKNOWN, not trusted: VPE withheld), `follow()`
    turns the published heading with the vehicle's rotation only, integrated at each withheld tick: the autopilot's
    own yaw followed its gyros meanwhile, so the first heading after the gap continues from the last one sent
    (rotated as the vehicle turned) and the slew resumes from there — no step of rate × gap, no rotation
    extrapolated over the gap from one yaw rate.

    VISION_POSITION_ESTIMATE.reset_counter is NOT touched by a calibration change: in ArduPilot a new
    reset_counter value makes AP_VisualOdom stamp a new reset time, which EKF3 (writeExtNavData) treats as a
    *position* reset (extNavDataNew.posReset), and the T265/VOXL backends drop 1 s of data after it; it
    never re-aligns yaw. So a heading change is slewed in, never signalled as a reset.
    """

    max_rate_deg_s: float = 2.0         # a calibration change
    done_within_deg: float = 0.05
    # the estimator needs a moment to take the new field (MEKF: `mag_min_undisturbed_s` of undisturbed field,
    # then its reference's time constant): the transition lasts at least this long, so it does not end before
    # the heading moves, s
    min_duration_s: float = 10.0
    active: bool = False
    _published: float | None = None
    _t_last: float | None = None
    _t_start: float | None = None
    _t_sent: float | None = None        # sample time of the last heading sent (None: none, or a remembered one)
    hold_until_s: float | None = None   # until this sample time, follow the vehicle's rotation only
    rate_deg_s: float | None = None     # the running transition's rate (None: max_rate_deg_s)
    # the estimator's heading minus the published one at the last update (0 outside a transition), rad
    remaining_rad: float = 0.0
    reason: str = ""                    # why the running (or last) transition started, for the operator
    ended_why: str | None = None        # how the last transition ended (None: running, or none yet)

    def start_transition(self, rate_deg_s: float | None = None, reason: str = "calibration changed") -> None:
        """A calibration change (at `max_rate_deg_s`), or another transition at `rate_deg_s`."""
        self.active = True
        self._t_start = None      # set by the next update (sample time)
        self.hold_until_s = None
        self.rate_deg_s = rate_deg_s
        self.reason = reason
        self.ended_why = None

    def start_from(self, published_rad: float, hold_until_s: float | None = None,
                   rate_deg_s: float | None = None, reason: str = "restart") -> None:
        """A transition from a heading the autopilot already has (the one published before a restart):
        the published heading starts there, follows the vehicle's rotation, and — after `hold_until_s` if
        given — moves to the estimator's heading at `rate_deg_s` (default `max_rate_deg_s`)."""
        self._published = published_rad % (2 * math.pi)
        self._t_last = None
        self._t_sent = None           # the restart rule checked the remembered heading's age
        self.start_transition(rate_deg_s, reason)
        self.hold_until_s = hold_until_s

    def stop(self, why: str) -> None:
        """End a transition before the published heading reached the estimator's (a yaw reset replaces it,
        the autopilot re-aligned by other means, nobody receives it): from the next update the estimator's
        heading passes through."""
        if self.active:
            self.ended_why = why
        self.active = False
        self.remaining_rad = 0.0

    def published_sigma_rad(self, sigma_rad: float) -> float:
        """The 1σ of the published yaw for the estimator's yaw 1σ: σ + |remaining|/3 (estimator/slewed_yaw.py
        says why; docs/daemon.md "Calibration changes")."""
        return YawSlew.sigma_rad(sigma_rad, self.remaining_rad)

    def follow(self, t_s: float, heading_rad: float, yaw_rate_rad_s: float) -> None:
        """No heading is published at t_s (VPE withheld): during a transition the published heading turns with
        the vehicle's yaw rate over the time since the last call, without moving towards the estimator's."""
        if not self.active or self._published is None:
            return
        dt = 0.0 if self._t_last is None else max(0.0, t_s - self._t_last)
        self._t_last = t_s
        self._published = (self._published + yaw_rate_rad_s * dt) % (2 * math.pi)
        self.remaining_rad = float(wrap_pi(heading_rad - self._published))

    def release(self, rate_deg_s: float) -> None:
        """End a hold now: move from the held heading to the estimator's at `rate_deg_s`."""
        self.hold_until_s = None
        self.rate_deg_s = rate_deg_s

    @property
    def current_rate_deg_s(self) -> float:
        return self.max_rate_deg_s if self.rate_deg_s is None else self.rate_deg_s

    def update(self, t_s: float, heading_rad: float, yaw_rate_rad_s: float = 0.0, sigma_rad: float = 0.0) -> float:
        """Heading to publish (rad, [0, 2π)) for the estimator's heading at t_s, the vehicle's yaw rate and the
        estimator's yaw 1σ (the σ sent with the slewed heading sets its rate: estimator/slewed_yaw.py)."""
        if self.active and (self._published is None
                            or (self._t_sent is not None and t_s - self._t_sent > MAX_SLEW_FROM_AGE_S)):
            self.active = False       # the autopilot has no heading of ours to be brought from
            self.ended_why = "nothing sent before"
        self._t_sent = t_s
        if self._published is None or not self.active:
            self._published = heading_rad % (2 * math.pi)
            self._t_last = t_s
            self.remaining_rad = 0.0
            return self._published
        dt = 0.0 if self._t_last is None else max(0.0, t_s - self._t_last)
        self._t_last = t_s
        if self._t_start is None:
            self._t_start = t_s
        predicted = self._published + yaw_rate_rad_s * dt
        if self.hold_until_s is not None:
            if t_s < self.hold_until_s:
                self._published = predicted % (2 * math.pi)
                self._t_start = t_s
                self.remaining_rad = float(wrap_pi(heading_rad - self._published))
                return self._published
            self.hold_until_s = None
        to_go = float(wrap_pi(heading_rad - predicted))     # the estimator's heading minus the predicted one sent
        slew = YawSlew(math.radians(self.current_rate_deg_s), arrive_within_rad=math.radians(self.done_within_deg))
        move, arrived = slew.step(-to_go, sigma_rad, min(dt, MAX_STEP_INTERVAL_S))
        if arrived:
            self._published = heading_rad % (2 * math.pi)
            if abs(to_go) <= slew.arrive_within_rad and t_s - self._t_start >= self.min_duration_s:
                self.active = False
                self.ended_why = "slewed in"
        else:
            self._published = (predicted + move) % (2 * math.pi)
        self.remaining_rad = float(wrap_pi(heading_rad - self._published))
        return self._published
