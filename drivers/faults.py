"""Fault injection for the simulated ADIS16405: what can go wrong on a real unit, on demand.

A `FaultPlan` holds `Fault`s. Each is active on a window of the chip's sample index
(`start_sample <= index < stop_sample`), with an optional probability per event (seeded, replayable), and
can be switched on and off at run time (`fault.enabled`, `plan.enable(kind, False)`). The chip asks the plan
`plan.active(kind, index)` at the place the fault acts and counts what it injected in `plan.injected`.
"""

from __future__ import annotations

import enum
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from .registers import DiagStat


class FaultKind(str, enum.Enum):
    ALARM = "alarm"                    # EA on the output words with `diag_bits` latched in DIAG_STAT
    SELF_TEST_FAIL = "self_test_fail"  # the internal self-test reports `diag_bits`
    STUCK_AXIS = "stuck_axis"          # `axis` (0..8: gyro xyz, accel xyz, mag xyz) frozen at its onset value
    SATURATION = "saturation"          # `axis` driven to full scale (sign of `sign`), DIAG_STAT over-range
    GARBAGE = "garbage"                # the bus returns random bytes instead of the response
    BURST_BUG = "burst_bug"            # negative X-gyro comes back with bit 13 cleared in bursts (EZ 81805)
    BUS_ERROR = "bus_error"            # transfer raises OSError(ENODEV): the device is gone
    SHORT_READ = "short_read"          # transfer returns only the first half of the bytes
    STALL = "stall"                    # data-ready stalls: no new samples (ND stays clear)


AXIS_NAMES = ("gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z", "mag_x", "mag_y", "mag_z")


@dataclass
class Fault:
    kind: FaultKind
    start_sample: int = 0
    stop_sample: int | None = None      # exclusive; None: until disabled
    probability: float = 1.0            # chance per event while in the window
    axis: int = 0
    sign: int = 1
    diag_bits: int = int(DiagStat.ALARM1)
    enabled: bool = True

    def __post_init__(self):
        self.kind = FaultKind(self.kind)
        if not 0 <= self.axis < 9:
            raise ValueError(f"axis must be 0..8 ({', '.join(AXIS_NAMES)}), not {self.axis}")
        if not 0.0 <= self.probability <= 1.0:
            raise ValueError(f"probability must be in [0, 1], not {self.probability}")

    def in_window(self, index: int) -> bool:
        return self.enabled and index >= self.start_sample and (self.stop_sample is None or index < self.stop_sample)


@dataclass
class FaultPlan:
    """The faults a SimulatedAdis16405 injects. Empty plan = a healthy chip."""

    faults: list[Fault] = field(default_factory=list)
    seed: int = 0
    injected: Counter = field(default_factory=Counter)

    def __post_init__(self):
        self.rng = np.random.default_rng(self.seed)

    def add(self, kind: FaultKind | str, **kw) -> Fault:
        fault = Fault(FaultKind(kind), **kw)
        self.faults.append(fault)
        return fault

    def remove(self, fault: Fault) -> None:
        self.faults.remove(fault)

    def clear(self) -> None:
        self.faults.clear()

    def enable(self, kind: FaultKind | str, on: bool = True) -> None:
        """Switch every fault of this kind on or off (run-time toggle)."""
        kind = FaultKind(kind)
        for f in self.faults:
            if f.kind is kind:
                f.enabled = on

    def __bool__(self) -> bool:
        return any(f.enabled for f in self.faults)

    def active(self, kind: FaultKind, index: int) -> Fault | None:
        """The first enabled fault of `kind` active at sample `index` (probability drawn), counted if so."""
        for f in self.faults:
            if f.kind is kind and f.in_window(index):
                if f.probability >= 1.0 or self.rng.random() < f.probability:
                    self.injected[kind.value] += 1
                    return f
        return None

    def random_bytes(self, n: int) -> bytes:
        return self.rng.integers(0, 256, n, dtype=np.uint8).tobytes()
