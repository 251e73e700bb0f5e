"""The heading an estimator publishes, kept free of steps: a correction faster than a bounded rate (a yaw reset to
the GNSS yaw, the first GNSS fixes after the yaw σ was raised) is absorbed as an offset between the filter's
own yaw and the published one, and the offset is slewed out at no more than `max_rate_rad_s`.

What real INSs do: the filter keeps its internal yaw; the output stays continuous and either announces the
discontinuity (PX4 `quat_reset_counter`/`delta_q_reset`, ArduPilot `yawResetAngle`) or blends it in. ahrsd
blends, because the consumer it feeds — ArduPilot EKF3 through VISION_POSITION_ESTIMATE — has no yaw reset
input (`reset_counter` is a position reset there) and rejects a yaw step beyond its 3σ gate in flight
(../shared/anchors/heading-integrity.md §7, ardupilot-extnav.md).

Which change is a correction: the filter's yaw change between two samples minus the yaw change the body
rate explains (the ZYX Euler kinematics ψ̇ = (q sinφ + r cosφ)/cosθ, trapezoidal over the interval). The
vehicle's own rotation is never slowed; a correction up to `max_rate_rad_s`·Δt passes at once (the filter's
routine updates), only the excess enters the offset.

The slew is estimator/slewed_yaw.YawSlew, the one the daemon's slews build on too: the published 1σ covers the
offset and the rate is held down while that σ is large (σ_pub = σ + |offset|/3, so 3σ_pub covers the offset and the
filter's own 3σ; no more than 2 °/s while σ_pub is above EKF3's 5° floor, so an autopilot fusing it follows). What
is particular here is which change is a correction (above) and that the offset is kept, not the published yaw."""

from __future__ import annotations

import math

from .slewed_yaw import YawSlew

_TWO_PI = 2.0 * math.pi
_MIN_COS_PITCH = 1e-3    # at ±90° pitch yaw is undefined: every change there counts as motion


class PublishedHeading:
    """Offset (rad) to add to the filter's yaw for the published yaw. `update` once per sample (ins's step: the
    slew integrates over sample time, however seldom an estimate is built); `reset` when the filter
    re-initialises (the published heading then starts again from the filter's)."""

    def __init__(self, max_rate_rad_s: float):
        if not (max_rate_rad_s > 0.0):
            raise ValueError(f"max_rate_rad_s must be > 0, got {max_rate_rad_s!r}")
        self.max_rate_rad_s = float(max_rate_rad_s)
        self._slew = YawSlew(self.max_rate_rad_s)
        self.offset_rad = 0.0
        self.absorbed = 0            # samples at which a correction faster than the rate was absorbed
        self._t_s = math.nan
        self._yaw = math.nan
        self._yaw_rate = math.nan

    def reset(self) -> None:
        self.offset_rad = 0.0
        self._t_s = math.nan
        self._yaw = math.nan
        self._yaw_rate = math.nan

    def update(self, t_s: float, yaw_rad: float, roll_rad: float, pitch_rad: float, rate_body_rad_s,
               sigma_rad: float = 0.0) -> float:
        """The offset for the filter's yaw (any north: only differences are used) at t_s, its roll, pitch,
        bias-corrected body rate (rad/s) and yaw 1σ (with the offset it sets the slew rate: slewed_yaw.py)."""
        # once per sample at 819.2 SPS, so written out without helper calls (a call costs more than its
        # arithmetic) but the slew's step, shared with the daemon: ψ̇ of the ZYX kinematics, and angles
        # wrapped to ±π as (a + π) mod 2π − π
        cp = math.cos(pitch_rad)
        if abs(cp) < _MIN_COS_PITCH:
            rate = math.nan
        else:
            rate = (rate_body_rad_s[1] * math.sin(roll_rad) + rate_body_rad_s[2] * math.cos(roll_rad)) / cp
        dt = t_s - self._t_s
        if not (dt > 0.0) or not math.isfinite(self._yaw) or not math.isfinite(yaw_rad):
            if not math.isfinite(yaw_rad):
                self.reset()
            else:
                self._t_s, self._yaw, self._yaw_rate = t_s, yaw_rad, rate
            return self.offset_rad
        change = (yaw_rad - self._yaw + math.pi) % _TWO_PI - math.pi
        if math.isfinite(rate) and math.isfinite(self._yaw_rate):
            correction = (change - 0.5 * (rate + self._yaw_rate) * dt + math.pi) % _TWO_PI - math.pi
        else:
            correction = 0.0
        self._t_s, self._yaw, self._yaw_rate = t_s, yaw_rad, rate
        o = (self.offset_rad - correction + math.pi) % _TWO_PI - math.pi
        move, arrived = self._slew.step(o, sigma_rad, dt)
        if not arrived and abs(correction) > abs(move):      # more came in than one step takes out
            self.absorbed += 1
        self.offset_rad = o + move
        return self.offset_rad

    def published_sigma(self, sigma_rad: float) -> float:
        """The published yaw 1σ for the filter's 1σ: σ + |offset|/3 (slewed_yaw.py)."""
        return self._slew.sigma_rad(sigma_rad, self.offset_rad) if self.offset_rad else sigma_rad
