"""The sample that flows from the driver through calibration into the estimator (CONTRIBUTING.md).

Body frame FRD after mounting; SI units. Magnetic field in µT.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field, replace

import numpy as np

from ahrsd.core.slot_init import slot_init


class SampleFlags(enum.IntFlag):
    """Status of one sample. Anything but NONE/NEW_DATA tells consumers to look closer."""

    NONE = 0
    NEW_DATA = 1 << 0          # ND bit was set on the burst words (fresh sample since last read)
    ALARM = 1 << 1             # EA bit set on any word: DIAG_STAT was read (see ImuSample.diag_stat)
    GYRO_SATURATED = 1 << 2    # at least one gyro axis at the range limit
    ACCEL_SATURATED = 1 << 3
    MAG_SATURATED = 1 << 4
    BURST_BUG_RECOVERED = 1 << 5  # X-gyro bit-13 burst bug detected and fixed by a register read
    STALE = 1 << 6             # ND clear: the chip had no new data (repeat of the previous sample)
    GYRO_INVALID = 1 << 7      # gyro values must not be used (self-test fail, stuck, over-range...)
    ACCEL_INVALID = 1 << 8
    MAG_INVALID = 1 << 9
    GAP_BEFORE = 1 << 10       # one or more samples were lost before this one


@slot_init       # built once per sample: the cheaper __init__
@dataclass(frozen=True, slots=True)
class ImuSample:
    """One calibrated-or-raw IMU sample in SI units.

    t_s: sample time in seconds of a monotonic clock (from the sample counter and the sample period).
    gyro_rad_s, accel_m_s2 (specific force: +9.81 on the up axis at rest), mag_ut: shape (3,) float64.
    """

    t_s: float
    gyro_rad_s: np.ndarray
    accel_m_s2: np.ndarray
    mag_ut: np.ndarray
    temp_c: float = float("nan")
    supply_v: float = float("nan")
    flags: SampleFlags = SampleFlags.NONE
    diag_stat: int = 0         # raw DIAG_STAT when ALARM was seen, else 0
    counter: int = 0           # sample index since the driver started (gaps increment it)

    def with_values(self, **changes) -> "ImuSample":
        """A copy with some fields replaced (calibration uses this)."""
        return replace(self, **changes)


_FLOAT64 = np.dtype(np.float64)


def _vector3(v) -> np.ndarray:
    """`v` as a float64 array of shape (3,). A row of an (n, 3) float64 array, what a per-sample loop passes, is
    one already and is taken as it is: np.asarray would return it too, and reshape a view of the same memory,
    at twice the cost of the checks (make_sample runs once per sample of every replay and simulation)."""
    if v.__class__ is np.ndarray and v.dtype is _FLOAT64 and v.shape == (3,):
        return v
    return np.asarray(v, dtype=np.float64).reshape(3)


_NDARRAY, _SHAPE3 = np.ndarray, (3,)


def make_sample(t_s: float, gyro_rad_s, accel_m_s2, mag_ut, **kw) -> ImuSample:
    """Convenience constructor that coerces the vectors to float64 arrays of shape (3,)."""
    # _vector3's test inline (three calls fewer per sample); what fails it goes through _vector3
    g, a, m = gyro_rad_s, accel_m_s2, mag_ut
    if not (g.__class__ is _NDARRAY and g.dtype is _FLOAT64 and g.shape == _SHAPE3):
        g = _vector3(g)
    if not (a.__class__ is _NDARRAY and a.dtype is _FLOAT64 and a.shape == _SHAPE3):
        a = _vector3(a)
    if not (m.__class__ is _NDARRAY and m.dtype is _FLOAT64 and m.shape == _SHAPE3):
        m = _vector3(m)
    return ImuSample(float(t_s), g, a, m, **kw)
