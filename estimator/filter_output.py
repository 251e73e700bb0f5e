"""What every filter hands out: the AttitudeEstimate of its output record,
EstimateFlags from the kernels' int bits, the flags of the first estimate after an initialisation, the estimate of
a filter that could not initialise yet, and where a field of an output record lies in its flat view. Shared by mekf
and ins."""

from __future__ import annotations

import math

import numpy as np

from ahrsd.core.estimate import AttitudeEstimate, EstimateFlags, HeadingState

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
    return AttitudeEstimate(t_s, out[fields.q], roll_rad, pitch_rad, yaw_rad, yaw_rad % _TWO_PI,
                            heading_true_rad % _TWO_PI, out[fields.rate], out[fields.bias], out[fields.sigma],
                            estimate_flags(flag_bits), nav, heading_state, integrity)
