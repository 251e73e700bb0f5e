"""A sample as the reader process hands it over: the 15 numbers of one hand-over record (drivers.process_source
`_RECORD`: t_s, gyro rad/s ×3, accel m/s² ×3, mag µT ×3, temp_c, supply_v, flags, diag_stat, counter) in a
tuple, made by the driver straight from the frame's integers.

Why: in the reader process every sample is read after its own wake, with cold caches, and packed for the pipe a
few milliseconds later; an ImuSample there (a numpy array of the nine values, three views of it, a frozen
dataclass, a SampleFlags) is built only to be taken apart again by the packing. The chip's sources read a sample's
`flags`, `t_s` and `counter` on the way (drivers.chip_source, ground_truth, threaded_source), which the record
gives as an ImuSample does; `flags` is the plain int (ImuSample's SampleFlags has the same value)."""

from __future__ import annotations

from operator import itemgetter

import numpy as np

_T_S, _GYRO, _ACCEL, _MAG, _TEMP_C, _SUPPLY_V, _FLAGS, _DIAG_STAT, _COUNTER = 0, 1, 4, 7, 10, 11, 12, 13, 14
_FIELD_INDEX = {"t_s": _T_S, "temp_c": _TEMP_C, "supply_v": _SUPPLY_V, "flags": _FLAGS, "diag_stat": _DIAG_STAT,
                "counter": _COUNTER}


class SampleRecord(tuple):
    """(t_s, gx, gy, gz, ax, ay, az, mx, my, mz, temp_c, supply_v, flags, diag_stat, counter): what `pack` writes
    as it is. Read like an ImuSample (the vectors are built when asked)."""

    __slots__ = ()

    t_s = property(itemgetter(_T_S))
    temp_c = property(itemgetter(_TEMP_C))
    supply_v = property(itemgetter(_SUPPLY_V))
    flags = property(itemgetter(_FLAGS))
    diag_stat = property(itemgetter(_DIAG_STAT))
    counter = property(itemgetter(_COUNTER))
    gyro_rad_s = property(lambda self: np.array(self[_GYRO:_GYRO + 3]))
    accel_m_s2 = property(lambda self: np.array(self[_ACCEL:_ACCEL + 3]))
    mag_ut = property(lambda self: np.array(self[_MAG:_MAG + 3]))

    def with_values(self, **changes) -> "SampleRecord":
        """A copy with some of its scalar fields replaced (as ImuSample.with_values: a gap flag set on the way)."""
        values = list(self)
        for name, value in changes.items():
            values[_FIELD_INDEX[name]] = value
        return SampleRecord(values)
