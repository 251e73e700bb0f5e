"""The GNSS fix every GNSS source delivers (CONTRIBUTING.md): a receiver's position and velocity solution.

Time: `t_s` is the time of validity of the solution on the pipeline's clock (the IMU samples' `t_s`), i.e.
the arrival time minus the receiver latency the source knows or is configured with. Missing values are NaN
(GPS_RAW_INT and NMEA carry no vertical velocity; NMEA carries no accuracies).
"""

from __future__ import annotations

import dataclasses
import enum
import math
from dataclasses import dataclass, field

import numpy as np

from ahrsd.core.slot_init import slot_init


class GnssFixType(enum.IntEnum):
    """The receiver's fix, numbered as MAVLink GPS_FIX_TYPE (0 no GPS ... 6 RTK fixed)."""

    NO_GPS = 0
    NO_FIX = 1
    FIX_2D = 2
    FIX_3D = 3
    DGPS = 4
    RTK_FLOAT = 5
    RTK_FIXED = 6


@slot_init       # built once per fix: the cheaper __init__ (core/slot_init.py)
@dataclass(frozen=True, slots=True)
class GnssFix:
    """One GNSS solution in SI units. Position WGS-84 geodetic (alt above the ellipsoid); velocity NED."""

    t_s: float
    lat_deg: float
    lon_deg: float
    alt_m: float
    vel_ned_m_s: np.ndarray                  # (3,) north, east, down; down may be NaN (not reported)
    h_acc_m: float = float("nan")            # 1σ horizontal position accuracy as the receiver reports it
    v_acc_m: float = float("nan")
    s_acc_m_s: float = float("nan")          # 1σ speed accuracy
    fix_type: GnssFixType = GnssFixType.FIX_3D
    num_sats: int = -1                       # -1: not reported
    source: str = ""                         # which source made it (for logs and status)
    extra: dict = field(default_factory=dict, compare=False)
    hdop: float = float("nan")               # horizontal dilution of precision (NMEA GGA, GPS_RAW_INT eph)

    @property
    def has_position(self) -> bool:
        return self.fix_type >= GnssFixType.FIX_2D and math.isfinite(self.lat_deg) and math.isfinite(self.lon_deg)

    @property
    def has_velocity(self) -> bool:
        return self.fix_type >= GnssFixType.FIX_2D and bool(np.all(np.isfinite(self.vel_ned_m_s[:2])))

    @property
    def ground_speed_m_s(self) -> float:
        return math.hypot(float(self.vel_ned_m_s[0]), float(self.vel_ned_m_s[1]))

    @property
    def course_rad(self) -> float:
        """Course over ground, [0, 2π) from true north (meaningless at low speed)."""
        return math.atan2(float(self.vel_ned_m_s[1]), float(self.vel_ned_m_s[0])) % (2.0 * math.pi)


# The 1σ assumed where a source does not report one (NMEA, the autopilot's GLOBAL_POSITION_INT, a recording
# without the columns): the one definition, used by the recording reader and by the aided estimator alike, so a
# live fix and the same fix replayed from a recording weigh the same. The receiver is a u-blox M8-class one in
# open sky (u-blox NEO-M8 data sheet, UBX-15031086: horizontal position 2.5 m CEP, velocity 0.05 m/s at 50 %).
# h: per axis (north, east), as the filter uses it: the CEP of a circular normal is sqrt(2 ln 2) σ = 1.177 σ,
#    2.5 / 1.177 = 2.1 m.
# v: the data sheet gives none; the GPS SPS Performance Standard (2008, §3.8) quotes well-designed receivers at
#    3 m horizontal and 5 m vertical 95 %: 2D 95 % is 2.448 σ, 1D 1.96 σ, so σ_v = 2.08 σ_h = 4.4 m.
# s: per axis; the 50 % figure read as the median absolute error of one axis (0.6745 σ), the larger of its
#    readings (the radial one gives 0.042): 0.05 / 0.6745 = 0.074 m/s.
DEFAULT_H_ACC_M = 2.1
DEFAULT_V_ACC_M = 4.4
DEFAULT_S_ACC_M_S = 0.074


def with_default_accuracies(fix: GnssFix, h_acc_m: float = DEFAULT_H_ACC_M, v_acc_m: float = DEFAULT_V_ACC_M,
                            s_acc_m_s: float = DEFAULT_S_ACC_M_S) -> GnssFix:
    """The fix with every accuracy it does not report (NaN) replaced by the given default."""
    h, v, s = (fix.h_acc_m if math.isfinite(fix.h_acc_m) else h_acc_m,
               fix.v_acc_m if math.isfinite(fix.v_acc_m) else v_acc_m,
               fix.s_acc_m_s if math.isfinite(fix.s_acc_m_s) else s_acc_m_s)
    if (h, v, s) == (fix.h_acc_m, fix.v_acc_m, fix.s_acc_m_s):
        return fix
    return dataclasses.replace(fix, h_acc_m=float(h), v_acc_m=float(v), s_acc_m_s=float(s))


def make_fix(t_s, lat_deg, lon_deg, alt_m, vel_ned_m_s, **kw) -> GnssFix:
    """Convenience constructor that coerces the velocity to a float64 array of shape (3,)."""
    return GnssFix(float(t_s), float(lat_deg), float(lon_deg), float(alt_m),
                   np.asarray(vel_ned_m_s, dtype=np.float64).reshape(3), **kw)
