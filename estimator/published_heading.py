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

import numpy as np
from numba import njit

from .slewed_yaw import YawSlew
from .slewed_yaw_kernel import slew_step

_TWO_PI = 2.0 * math.pi
_MIN_COS_PITCH = 1e-3    # at ±90° pitch yaw is undefined: every change there counts as motion
# the state's slots (`PublishedHeading.state`, what the compiled step reads and writes)
OFFSET, T_S, YAW, YAW_RATE, ABSORBED, FOLLOWING = range(6)


class PublishedHeading:
    """Offset (rad) to add to the filter's yaw for the published yaw. `update` once per sample (ins's step: the
    slew integrates over sample time, however seldom an estimate is built); `reset` when the filter
    re-initialises (the published heading then starts again from the filter's). The state is one float64 array
    (`state`: the offset, the last sample's time, yaw and yaw rate, the samples absorbed, and whether the filter's
    estimates are followed yet, which ins sets), so that ins's compiled run of a block's samples steps it too
    (ins_step_block.py), with the same compiled step (`published_offset_step`)."""

    def __init__(self, max_rate_rad_s: float):
        if not (max_rate_rad_s > 0.0):
            raise ValueError(f"max_rate_rad_s must be > 0, got {max_rate_rad_s!r}")
        self.max_rate_rad_s = float(max_rate_rad_s)
        self.state = np.array([0.0, math.nan, math.nan, math.nan, 0.0, 0.0])

    @property
    def offset_rad(self) -> float:
        return float(self.state[OFFSET])

    @property
    def absorbed(self) -> int:
        """Samples at which a correction faster than the rate was absorbed."""
        return int(self.state[ABSORBED])

    def reset(self) -> None:
        published_reset(self.state)

    def update(self, t_s: float, yaw_rad: float, roll_rad: float, pitch_rad: float, rate_body_rad_s,
               sigma_rad: float = 0.0) -> float:
        """The offset for the filter's yaw (any north: only differences are used) at t_s, its roll, pitch,
        bias-corrected body rate (rad/s) and yaw 1σ (with the offset it sets the slew rate: slewed_yaw.py)."""
        return published_offset_step(self.state, self.max_rate_rad_s, float(t_s), float(yaw_rad), float(roll_rad),
                                     float(pitch_rad), float(rate_body_rad_s[1]), float(rate_body_rad_s[2]),
                                     float(sigma_rad))

    def published_sigma(self, sigma_rad: float) -> float:
        """The published yaw 1σ for the filter's 1σ: σ + |offset|/3 (slewed_yaw.py)."""
        offset = self.offset_rad
        return YawSlew.sigma_rad(sigma_rad, offset) if offset else sigma_rad


@njit(cache=True)
def published_reset(state) -> None:
    """PublishedHeading.reset on its state array: the published heading starts again from the filter's."""
    state[OFFSET] = 0.0
    state[T_S] = math.nan
    state[YAW] = math.nan
    state[YAW_RATE] = math.nan


@njit(cache=True)
def published_offset_step(state, max_rate_rad_s, t_s, yaw_rad, roll_rad, pitch_rad, rate_y_rad_s, rate_z_rad_s,
                          sigma_rad):
    """PublishedHeading.update on its state array: returns the new offset. ψ̇ of the ZYX kinematics, and angles
    wrapped to ±π as (a + π) mod 2π − π."""
    cp = math.cos(pitch_rad)
    if abs(cp) < _MIN_COS_PITCH:
        rate = math.nan
    else:
        rate = (rate_y_rad_s * math.sin(roll_rad) + rate_z_rad_s * math.cos(roll_rad)) / cp
    dt = t_s - state[T_S]
    if not (dt > 0.0) or not math.isfinite(state[YAW]) or not math.isfinite(yaw_rad):
        if not math.isfinite(yaw_rad):
            published_reset(state)
        else:
            state[T_S] = t_s
            state[YAW] = yaw_rad
            state[YAW_RATE] = rate
        return state[OFFSET]
    change = (yaw_rad - state[YAW] + math.pi) % _TWO_PI - math.pi
    if math.isfinite(rate) and math.isfinite(state[YAW_RATE]):
        correction = (change - 0.5 * (rate + state[YAW_RATE]) * dt + math.pi) % _TWO_PI - math.pi
    else:
        correction = 0.0
    state[T_S] = t_s
    state[YAW] = yaw_rad
    state[YAW_RATE] = rate
    o = (state[OFFSET] - correction + math.pi) % _TWO_PI - math.pi
    move, arrived = slew_step(max_rate_rad_s, 0.0, o, sigma_rad, dt)
    if not arrived and abs(correction) > abs(move):      # more came in than one step takes out
        state[ABSORBED] += 1.0
    state[OFFSET] = o + move
    return state[OFFSET]
