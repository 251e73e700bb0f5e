"""What every filter hands out: the AttitudeEstimate of its output record (and an aided filter's NavState),
EstimateFlags from the kernels' int bits, the flags of the first estimate after an initialisation, the estimate of
a filter that could not initialise yet, and where a field of an output record lies in its flat view. Shared by mekf
and ins."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ahrsd.core.estimate import AttitudeEstimate, EstimateFlags, HeadingState, NavState

_FLAG_CACHE: dict[int, EstimateFlags] = {}
_TWO_PI = 2.0 * math.pi


def float_field_slice(dtype: np.dtype, name: str) -> slice:
    """Where the float64 field `name` of the all-float64 record type `dtype` lies in its flat float64 view (a
    slice of a flat array costs less than a field lookup on a record)."""
    if any(f[0].base != np.float64 for f in dtype.fields.values()):
        raise TypeError(f"{dtype}: a flat float64 view needs every field float64")
    sub, offset = dtype.fields[name][:2]
    return slice(offset // 8, offset // 8 + sub.itemsize // 8)


def estimate_flags(bits: int) -> EstimateFlags:
    """EstimateFlags of an int, cached (building an IntFlag costs more than the whole filter step)."""
    f = _FLAG_CACHE.get(bits)
    if f is None:
        f = _FLAG_CACHE[bits] = EstimateFlags(bits & 0xFFFF)
    return f


def after_init_flags(reinitialised: bool, mag_enabled: bool) -> int:
    """Flags of the first estimate after an initialisation (REINITIALISED | LARGE_DT after a time gap)."""
    f = int(EstimateFlags.INITIALISING)
    if reinitialised:
        f |= int(EstimateFlags.REINITIALISED | EstimateFlags.LARGE_DT)
    if not mag_enabled:
        f |= int(EstimateFlags.MAG_UNAVAILABLE)
    return f


def uninitialised_estimate(t_s: float, flag_bits: int) -> AttitudeEstimate:
    """The estimate of a filter that could not initialise yet: NaN angles, INITIALISING | flag_bits."""
    nan3 = np.full(3, np.nan)
    return AttitudeEstimate(
        t_s=t_s,
        q_wxyz=np.array([1.0, 0.0, 0.0, 0.0]),
        roll_rad=math.nan,
        pitch_rad=math.nan,
        yaw_rad=math.nan,
        heading_mag_rad=math.nan,
        heading_true_rad=math.nan,
        rate_body_rad_s=nan3,
        gyro_bias_rad_s=np.zeros(3),
        sigma_rpy_rad=np.full(3, math.pi),
        flags=EstimateFlags.INITIALISING | estimate_flags(flag_bits),
        heading_state=HeadingState.UNKNOWN,
    )


class AttitudeFields:
    """Where the attitude outputs lie in the flat float64 view of a filter's output record type: the fields
    every filter's output record has (`q`, `rate_rad_s`, `gyro_bias_rad_s`, `sigma_rpy_rad`, `euler_rad`)."""

    __slots__ = ("q", "rate", "bias", "sigma", "euler")

    def __init__(self, dtype: np.dtype):
        self.q, self.rate, self.bias, self.sigma, self.euler = (float_field_slice(dtype, name) for name in (
            "q", "rate_rad_s", "gyro_bias_rad_s", "sigma_rpy_rad", "euler_rad"))


def attitude_estimate(t_s: float, out: np.ndarray, fields: AttitudeFields, roll_rad: float, pitch_rad: float,
                      yaw_rad: float, heading_true_rad: float, flag_bits: int, heading_state: HeadingState,
                      nav=None, integrity=None) -> AttitudeEstimate:
    """The estimate of a filter's outputs. out: a fresh copy of the flat view of its output record (the
    estimate's quaternion, rate, bias and σ are views of it, so the caller must not reuse it); yaw_rad
    magnetic, heading_true_rad = yaw + declination (both wrapped here to [0, 2π) for the headings)."""
    e = _new(AttitudeEstimate)
    _set_t(e, t_s)
    _set_q(e, out[fields.q])
    _set_roll(e, roll_rad)
    _set_pitch(e, pitch_rad)
    _set_yaw(e, yaw_rad)
    _set_mag(e, yaw_rad % _TWO_PI)
    _set_true(e, heading_true_rad % _TWO_PI)
    _set_rate(e, out[fields.rate])
    _set_bias(e, out[fields.bias])
    _set_sigma(e, out[fields.sigma])
    _set_flags(e, estimate_flags(flag_bits))
    _set_nav(e, nav)
    _set_state(e, heading_state)
    _set_integrity(e, integrity)
    return e


# AttitudeEstimate and NavState are frozen dataclasses with slots: their generated __init__ sets each field through
# object.__setattr__ (the class's own __setattr__ raises), about twice what setting the slot through its descriptor
# costs, and every filter builds one (ins two) with every estimate it builds. `attitude_estimate` and `nav_state`
# set the slots directly; these are all their fields, in order, and nothing else runs at construction (no
# __post_init__, every field an __init__ argument), else they must not.
_ATT_FIELDS = ("t_s", "q_wxyz", "roll_rad", "pitch_rad", "yaw_rad", "heading_mag_rad", "heading_true_rad",
               "rate_body_rad_s", "gyro_bias_rad_s", "sigma_rpy_rad", "flags", "nav", "heading_state", "integrity")
_NAV_FIELDS = ("vel_ned_m_s", "lat_deg", "lon_deg", "alt_m", "sigma_vel_m_s", "sigma_pos_m", "accel_bias_m_s2")
for _cls, _names in ((AttitudeEstimate, _ATT_FIELDS), (NavState, _NAV_FIELDS)):
    if (tuple(f.name for f in dataclasses.fields(_cls)) != _names
            or not all(f.init for f in dataclasses.fields(_cls)) or hasattr(_cls, "__post_init__")
            or "__slots__" not in _cls.__dict__ or not _cls.__dataclass_params__.frozen):
        raise TypeError(f"{_cls.__name__} changed: its builder must set exactly its fields (estimator/filter_output.py)")
_new = _new_nav = object.__new__
(_set_t, _set_q, _set_roll, _set_pitch, _set_yaw, _set_mag, _set_true, _set_rate, _set_bias, _set_sigma, _set_flags,
 _set_nav, _set_state, _set_integrity) = (getattr(AttitudeEstimate, name).__set__ for name in _ATT_FIELDS)
_set_vel, _set_lat, _set_lon, _set_alt, _set_sigma_vel, _set_sigma_pos, _set_accel_bias = (
    getattr(NavState, name).__set__ for name in _NAV_FIELDS)


def nav_state(vel_ned_m_s: np.ndarray, lat_deg: float, lon_deg: float, alt_m: float, sigma_vel_m_s: np.ndarray,
              sigma_pos_m: np.ndarray, accel_bias_m_s2: np.ndarray) -> NavState:
    """NavState(vel_ned_m_s, lat_deg, …, accel_bias_m_s2): the same object, built for half the cost (above)."""
    n = _new_nav(NavState)
    _set_vel(n, vel_ned_m_s)
    _set_lat(n, lat_deg)
    _set_lon(n, lon_deg)
    _set_alt(n, alt_m)
    _set_sigma_vel(n, sigma_vel_m_s)
    _set_sigma_pos(n, sigma_pos_m)
    _set_accel_bias(n, accel_bias_m_s2)
    return n
