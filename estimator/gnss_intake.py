"""The GNSS fixes `ins` is offered, before the kernel sees them: which are taken now, which wait for the IMU
samples to reach their time, which are refused, what of a taken fix is usable and how much each part is trusted;
and the count of what became of every fix (`GnssCounters`, what the daemon's GNSS task and replay's summary read).

A fix arrives 50–200 ms after its time of validity and is fused against the state history at that time
(ins_core.fuse_gnss, the delayed-measurement idea of ArduPilot EKF3's fusion time horizon); one ahead of the
samples waits in a short queue. Bad input never raises: a malformed fix, no fix, non-finite fields, a time not
after the previous fix's, one too far ahead are counted and logged, and the filter flags GNSS_REJECTED on its next
estimate (told through `on_reject`). The part owns its queue, its last fix time and its counters; what the filter
does with a usable fix stays with the filter.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, fields
from typing import Callable, NamedTuple

import numpy as np

from ahrsd.core.gnss import DEFAULT_H_ACC_M, DEFAULT_S_ACC_M_S, DEFAULT_V_ACC_M, GnssFix, GnssFixType

from . import ins_core as core

log = logging.getLogger("ahrsd.estimator.ins")    # the filter's own log: what the daemon's operator reads as ins's


@dataclass
class GnssCounters:
    """What became of the fixes offered to `update_gnss` (each fix counts once in `offered`)."""

    offered: int = 0
    fused_velocity: int = 0
    fused_position: int = 0
    rejected_velocity: int = 0      # χ² gate (a spike)
    rejected_position: int = 0      # χ² gate (a jump)
    reset_velocity: int = 0         # after reject_reset_s of rejections: re-acquired
    reset_position: int = 0
    nav_initialised: int = 0        # first fix, or first after nav_drop_s
    nav_reset_after_outage: int = 0  # first fix after outage_reset_s: velocity and position set from it
    invalid: int = 0                # no fix, non-finite position and velocity, bad accuracies
    time_backwards: int = 0         # not newer than the previous fix
    too_old: int = 0                # older than max_delay_s / the history
    queued: int = 0                 # ahead of the IMU: held until the samples reach it
    before_init: int = 0            # offered before the attitude was initialised

    def as_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}


class FixParts(NamedTuple):
    """What of a fix is fused: its time, position (°, m), NED velocity (m/s), each part's 1σ (m, m, m/s: the
    receiver's, or the default when it gave none, never below the filter's floor) and which parts are usable."""

    t_s: float
    lat_deg: float
    lon_deg: float
    alt_m: float
    vel_ned_m_s: np.ndarray
    sigma_h_m: float
    sigma_v_m: float
    sigma_s_m_s: float
    use_pos: bool
    use_alt: bool
    use_vel: bool
    use_vd: bool


class GnssFixIntake:
    """The fixes offered to the filter (module docstring).

    max_queued: the fixes held ahead of the samples at most; use_vertical_velocity, min_h_acc_m, min_v_acc_m,
    min_s_acc_m_s, reject_reset_s: InsParams's; on_reject: called for every fix refused or rejected (the filter flags
    GNSS_REJECTED on its next estimate)."""

    def __init__(self, *, max_queued: int, use_vertical_velocity: bool, min_h_acc_m: float, min_v_acc_m: float,
                 min_s_acc_m_s: float, reject_reset_s: float, on_reject: Callable[[], None]):
        self._max_queued = max_queued
        self._use_vertical_velocity = use_vertical_velocity
        self._min_h_acc_m = min_h_acc_m
        self._min_v_acc_m = min_v_acc_m
        self._min_s_acc_m_s = min_s_acc_m_s
        self._reject_reset_s = reject_reset_s
        self._on_reject = on_reject
        self.counters = GnssCounters()
        # the fixes ahead of the samples, oldest first; read by the filter on every sample (is one waiting?)
        self.queue: list[GnssFix] = []
        self._last_fix_t = -math.inf

    def reset(self) -> None:
        """The filter starts again: no fix waits, any time is after the last fix's. The counters go on."""
        self.queue.clear()
        self._last_fix_t = -math.inf

    def drop_queued(self) -> None:
        """The filter restarts after a gap: the fixes waiting for samples are of the run before."""
        self.queue.clear()

    def offer(self, fix: GnssFix, initialised: bool, t_last_s: float) -> bool:
        """One fix offered with the filter initialised or not, its samples up to t_last_s: True when it is to be
        fused now; else it was counted, and queued or refused."""
        c = self.counters
        c.offered += 1
        try:
            t = float(fix.t_s)
        except (TypeError, ValueError):
            t = math.nan
        if not math.isfinite(t):
            c.invalid += 1
            self._reject("non-finite time", fix)
            return False
        if t <= self._last_fix_t:
            c.time_backwards += 1
            self._reject(f"time {t:.3f} s not after the previous fix's {self._last_fix_t:.3f} s", fix)
            return False
        if not initialised:
            c.before_init += 1
            return False
        if t > t_last_s:
            if len(self.queue) >= self._max_queued:
                c.invalid += 1
                self._reject("too far ahead of the IMU samples", fix)
                return False
            c.queued += 1
            self._last_fix_t = t
            self.queue.append(fix)
            return False
        self._last_fix_t = t
        return True

    def pop_due(self, t_last_s: float) -> GnssFix | None:
        """The oldest queued fix the samples (up to t_last_s) have reached, taken from the queue; None if none."""
        if self.queue and self.queue[0].t_s <= t_last_s:
            return self.queue.pop(0)
        return None

    def read(self, fix: GnssFix) -> FixParts | None:
        """The usable parts of a fix to be fused, with their 1σ; None, counted invalid and rejected, when a field is
        malformed, there is no fix (below 2D), or neither position nor velocity is usable."""
        read = self._read_fix(fix)
        if read is None:
            return None
        fix_type, lat, lon, alt, v, h_acc, v_acc, s_acc = read
        use_pos, use_alt, use_vel, use_vd = usable_parts(fix_type, lat, lon, alt, v, self._use_vertical_velocity)
        if not (use_pos or use_vel):
            self.counters.invalid += 1
            self._reject("neither position nor velocity is finite", fix)
            return None
        return FixParts(float(fix.t_s), lat, lon, alt, v, _accuracy(h_acc, DEFAULT_H_ACC_M, self._min_h_acc_m),
                        _accuracy(v_acc, DEFAULT_V_ACC_M, self._min_v_acc_m),
                        _accuracy(s_acc, DEFAULT_S_ACC_M_S, self._min_s_acc_m_s), use_pos, use_alt, use_vel, use_vd)

    def _read_fix(self, fix: GnssFix) -> tuple | None:
        """The fix's fields as numbers: (fix type, lat °, lon °, alt m, NED velocity m/s, h/v/speed accuracy).
        None, counted invalid and rejected, when a field is malformed or there is no fix (below 2D)."""
        try:
            fix_type = int(fix.fix_type)
            lat = float(fix.lat_deg)
            lon = float(fix.lon_deg)
            alt = float(fix.alt_m)
            v = np.asarray(fix.vel_ned_m_s, dtype=float).reshape(3)
            h_acc, v_acc, s_acc = float(fix.h_acc_m), float(fix.v_acc_m), float(fix.s_acc_m_s)
        except (TypeError, ValueError, AttributeError):
            self.counters.invalid += 1
            self._reject("malformed fix", fix)
            return None
        if fix_type < GnssFixType.FIX_2D:
            self.counters.invalid += 1
            self._reject(f"no fix (type {fix_type})", fix)
            return None
        return fix_type, lat, lon, alt, v, h_acc, v_acc, s_acc

    def count(self, res: int, fix: GnssFix, velocity_nis: float, position_nis: float) -> None:
        """Count and log what fuse_gnss did with the fix (its R_* bits), the gates' NIS after it; rejections
        flag GNSS_REJECTED on the next estimate."""
        c = self.counters
        if res & core.R_TOO_OLD:
            c.too_old += 1
            self._reject("older than the state history", fix)
        if res & core.R_NAV_INIT:
            c.nav_initialised += 1
            log.info("ins: velocity and position set from the GNSS fix at t=%.3f s", fix.t_s)
        if res & core.R_OUTAGE_RESET:
            c.nav_reset_after_outage += 1
            log.info("ins: GNSS back after an outage: velocity and position reset to the fix at t=%.3f s", fix.t_s)
        c.fused_velocity += bool(res & core.R_VEL_FUSED)
        c.fused_position += bool(res & core.R_POS_FUSED)
        if res & core.R_VEL_REJECTED:
            c.rejected_velocity += 1
            self._reject(f"velocity innovation χ² {velocity_nis:.1f}", fix)
        if res & core.R_POS_REJECTED:
            c.rejected_position += 1
            self._reject(f"position innovation χ² {position_nis:.1f}", fix)
        if res & core.R_VEL_RESET:
            c.reset_velocity += 1
            log.warning("ins: GNSS velocity rejected for %.1f s: velocity reset to the fix", self._reject_reset_s)
        if res & core.R_POS_RESET:
            c.reset_position += 1
            log.warning("ins: GNSS position rejected for %.1f s: position reset to the fix", self._reject_reset_s)

    def _reject(self, why: str, fix) -> None:
        self._on_reject()
        log.info("ins: GNSS fix rejected (%s)", why)


def usable_parts(fix_type: int, lat: float, lon: float, alt: float, v: np.ndarray,
                 use_vertical_velocity: bool) -> tuple[bool, bool, bool, bool]:
    """Which parts of a fix are fused: (position, height, horizontal velocity, vertical velocity). Height
    needs a 3D fix and a position; the vertical velocity a horizontal one and `use_vertical_velocity`; each a
    finite value in range (a receiver's 'no value' is NaN or a huge number)."""
    use_pos = math.isfinite(lat) and math.isfinite(lon) and abs(lat) <= 90.0 and abs(lon) <= 360.0
    use_alt = use_pos and fix_type >= GnssFixType.FIX_3D and math.isfinite(alt) and abs(alt) < 1e5
    vn, ve = float(v[0]), float(v[1])
    use_vel = math.isfinite(vn) and math.isfinite(ve) and max(abs(vn), abs(ve)) < 600.0
    use_vd = use_vel and use_vertical_velocity and math.isfinite(v[2]) and abs(v[2]) < 600.0
    return use_pos, use_alt, use_vel, use_vd


def _accuracy(reported: float, default: float, floor: float) -> float:
    """A reported 1σ, the default when it is missing or not positive, never below the floor."""
    if not (math.isfinite(reported) and reported > 0.0):
        return default
    return max(reported, floor)


__all__ = ["FixParts", "GnssCounters", "GnssFixIntake", "usable_parts"]
