"""Validation of GnssFixes at the edge: every rejection counted, logged (rate-limited) with a reason.

`GnssFixValidator.check(fix) -> GnssRejection | None` (None: accepted). It never raises: anything that is
not a well-formed GnssFix is rejected as MALFORMED. Order of the checks: malformed, non-finite time, time
going backwards, time repeated (t_s, or the receiver's own epoch time `extra["receiver_time_s"]`), fix lost
(fix_type < 2D), non-finite fields, out of range, accuracies <= 0. Only an accepted fix moves the time
reference, so one bad time does not poison the next good fix.

Non-finite fields: latitude, longitude and horizontal velocity must be finite; altitude too from a 3D fix on
(a 2D fix and RMC-only NMEA have none); the down velocity and the accuracies may be NaN ("not reported") but
not infinite. Glitches in plausible values (a 50 m jump) are the estimator's innovation gate, not this.
"""

from __future__ import annotations

import enum
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ahrsd.core.gnss import GnssFix, GnssFixType

log = logging.getLogger(__name__)


class GnssRejection(str, enum.Enum):
    MALFORMED = "malformed"
    NONFINITE_TIME = "nonfinite_time"
    TIME_BACKWARDS = "time_backwards"
    TIME_REPEATED = "time_repeated"
    NO_FIX = "no_fix"
    NONFINITE_FIELD = "nonfinite_field"
    OUT_OF_RANGE = "out_of_range"
    BAD_ACCURACY = "bad_accuracy"


@dataclass(frozen=True)
class GnssLimits:
    """Plausible values. Altitude: the Dead Sea shore is −430 m MSL and the geoid lies up to ~106 m below the
    ellipsoid; receivers' own limits are 50 km and 500 m/s (u-blox airborne models; the export limit is
    ~515 m/s)."""

    min_alt_m: float = -1000.0
    max_alt_m: float = 60000.0
    max_speed_m_s: float = 600.0
    max_vertical_speed_m_s: float = 300.0
    log_interval_s: float = 10.0


class GnssFixValidator:
    """Counts accepted fixes and rejections by reason (`counters`), logs each reason at most once per
    `limits.log_interval_s` (with how many were not logged), keeps `last_rejection` and `last_detail`."""

    def __init__(self, limits: GnssLimits = GnssLimits(), clock: Callable[[], float] = time.monotonic,
                 name: str = "gnss"):
        self.limits, self.clock, self.name = limits, clock, name
        self.counters: dict[str, int] = {"accepted": 0, **{r.value: 0 for r in GnssRejection}}
        self.last_rejection: GnssRejection | None = None
        self.last_detail = ""
        self._last_t_s = -math.inf
        self._last_receiver_time_s = math.nan
        self._last_logged: dict[GnssRejection, float] = {}
        self._unlogged: dict[GnssRejection, int] = {}

    @property
    def rejected(self) -> int:
        return sum(v for k, v in self.counters.items() if k != "accepted")

    def check(self, fix) -> GnssRejection | None:
        try:
            verdict = self._check(fix)
        except Exception as exc:      # a malformed object must not take the caller down
            verdict = (GnssRejection.MALFORMED, f"{type(exc).__name__}: {exc}")
        if verdict is None:
            self.counters["accepted"] += 1
            self._last_t_s = fix.t_s
            self._last_receiver_time_s = fix.extra.get("receiver_time_s", math.nan)
            return None
        reason, detail = verdict
        self.counters[reason.value] += 1
        self.last_rejection, self.last_detail = reason, detail
        self._log(reason, detail)
        return reason

    # ------------------------------------------------------------------------------------------------ internal
    def _check(self, fix) -> tuple[GnssRejection, str] | None:
        lim = self.limits
        if not isinstance(fix, GnssFix):
            return GnssRejection.MALFORMED, f"not a GnssFix: {type(fix).__name__}"
        vel = np.asarray(fix.vel_ned_m_s, dtype=np.float64)
        if vel.shape != (3,):
            return GnssRejection.MALFORMED, f"velocity has shape {vel.shape}, expected (3,)"
        t = float(fix.t_s)
        if not math.isfinite(t):
            return GnssRejection.NONFINITE_TIME, f"t_s = {t}"
        if t < self._last_t_s:
            return GnssRejection.TIME_BACKWARDS, f"t_s {t:.3f} s < previous {self._last_t_s:.3f} s"
        if t == self._last_t_s:
            return GnssRejection.TIME_REPEATED, f"t_s {t:.3f} s repeated"
        rx_time = fix.extra.get("receiver_time_s", math.nan)
        if rx_time == self._last_receiver_time_s:
            return GnssRejection.TIME_REPEATED, f"receiver epoch {rx_time:.3f} s repeated"
        if fix.fix_type < GnssFixType.FIX_2D:
            return GnssRejection.NO_FIX, f"fix type {GnssFixType(fix.fix_type).name}"
        required = {"lat_deg": fix.lat_deg, "lon_deg": fix.lon_deg, "vel_n_m_s": vel[0], "vel_e_m_s": vel[1]}
        if fix.fix_type >= GnssFixType.FIX_3D:
            required["alt_m"] = fix.alt_m
        optional = {"alt_m": fix.alt_m, "vel_d_m_s": vel[2], "h_acc_m": fix.h_acc_m, "v_acc_m": fix.v_acc_m,
                    "s_acc_m_s": fix.s_acc_m_s}
        bad = [k for k, v in required.items() if not math.isfinite(v)]
        bad += [k for k, v in optional.items() if math.isinf(v)]
        if bad:
            return GnssRejection.NONFINITE_FIELD, "non-finite " + ", ".join(dict.fromkeys(bad))
        if not -90.0 <= fix.lat_deg <= 90.0 or not -180.0 <= fix.lon_deg <= 180.0:
            return GnssRejection.OUT_OF_RANGE, f"lat/lon {fix.lat_deg}, {fix.lon_deg} deg"
        if math.isfinite(fix.alt_m) and not lim.min_alt_m <= fix.alt_m <= lim.max_alt_m:
            return GnssRejection.OUT_OF_RANGE, f"altitude {fix.alt_m:.1f} m outside [{lim.min_alt_m}, {lim.max_alt_m}]"
        speed = math.hypot(vel[0], vel[1])
        if speed > lim.max_speed_m_s:
            return GnssRejection.OUT_OF_RANGE, f"ground speed {speed:.1f} m/s > {lim.max_speed_m_s}"
        if math.isfinite(vel[2]) and abs(vel[2]) > lim.max_vertical_speed_m_s:
            return GnssRejection.OUT_OF_RANGE, f"vertical speed {vel[2]:.1f} m/s > {lim.max_vertical_speed_m_s}"
        bad_acc = [f"{k} = {v}" for k, v in (("h_acc_m", fix.h_acc_m), ("v_acc_m", fix.v_acc_m),
                                             ("s_acc_m_s", fix.s_acc_m_s)) if v <= 0.0]
        if bad_acc:
            return GnssRejection.BAD_ACCURACY, "accuracy <= 0: " + ", ".join(bad_acc)
        return None

    def _log(self, reason: GnssRejection, detail: str) -> None:
        now = self.clock()
        last = self._last_logged.get(reason, -math.inf)
        if now - last < self.limits.log_interval_s:
            self._unlogged[reason] = self._unlogged.get(reason, 0) + 1
            return
        skipped = self._unlogged.pop(reason, 0)
        more = f" (+{skipped} more since the last report)" if skipped else ""
        log.warning("%s fix rejected (%s): %s; %d rejected so far%s", self.name, reason.value, detail,
                    self.counters[reason.value], more)
        self._last_logged[reason] = now
