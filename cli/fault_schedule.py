"""`ahrsd run --sim-faults SCHEDULE`: inject sensor faults into the simulated ADIS16405 at run time.

For reliability tests and the soak benchmark (bench/soak.py): the schedule becomes a `drivers.faults.FaultPlan`
handed to the simulated chip, so every fault travels the real path (bytes on the simulated bus → driver →
daemon). It is refused with a real sensor (`--spi`): faults are only ever simulated.

Grammar (times in seconds of chip time: run-time faults from the daemon's first read of the simulated chip, start-up
faults such as self_test_fail from when it opened it; drivers/ground_truth.py):

    SCHEDULE := ITEM (';' ITEM)*
    ITEM     := KIND '@' START ['-' STOP] [':' OPTION (',' OPTION)*]
    OPTION   := p=PROBABILITY | axis=AXIS | sign=+1|-1 | bits=DIAG_BITS | every=PERIOD_S | until=END_S

    KIND   one of drivers.faults.FaultKind: alarm, self_test_fail, stuck_axis, saturation, garbage, burst_bug,
           bus_error, short_read, stall
    AXIS   0..8 or gyro_x .. mag_z
    DIAG_BITS  an integer (0x1000) or DiagStat names joined by '+' (XGYRO_SELF_TEST+ALARM1)
    every  repeat the window with this period (until `until`, default 3600 s)

Examples: `bus_error@3-4` (device gone for a second), `garbage@1-2:p=0.05`, `alarm@5-5.5:bits=SUPPLY_LOW`,
`stuck_axis@6-9:axis=mag_x`, `stall@20-20.5:every=30`, `self_test_fail@0-3` (start-up self-test fails for 3 s).
"""

from __future__ import annotations

from dataclasses import dataclass

from ahrsd.drivers.faults import AXIS_NAMES, FaultKind, FaultPlan
from ahrsd.drivers.registers import DiagStat

DEFAULT_REPEAT_UNTIL_S = 3600.0
MAX_WINDOWS = 100_000   # a typo in `every` must not allocate millions of windows


class FaultScheduleError(ValueError):
    """The --sim-faults schedule cannot be parsed; the message names the item and what is allowed."""


@dataclass(frozen=True)
class FaultWindow:
    """One parsed window, in seconds of chip time (stop None = until the end)."""

    kind: FaultKind
    start_s: float
    stop_s: float | None
    options: dict

    def samples(self, rate_hz: float) -> tuple[int, int | None]:
        """The window as chip sample indices at `rate_hz` (start inclusive, stop exclusive)."""
        start = int(round(self.start_s * rate_hz))
        stop = None if self.stop_s is None else max(start + 1, int(round(self.stop_s * rate_hz)))
        return start, stop


def _float(item: str, name: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise FaultScheduleError(f"fault {item!r}: {name} {text!r} is not a number") from None
    if not value >= 0.0 or value == float("inf"):
        raise FaultScheduleError(f"fault {item!r}: {name} must be a finite number ≥ 0, not {text}")
    return value


def _axis(item: str, text: str) -> int:
    if text in AXIS_NAMES:
        return AXIS_NAMES.index(text)
    if text.isdigit() and int(text) < 9:
        return int(text)
    raise FaultScheduleError(f"fault {item!r}: axis {text!r} must be 0..8 or one of {', '.join(AXIS_NAMES)}")


def _bits(item: str, text: str) -> int:
    try:
        value = int(text, 0)
    except ValueError:
        value = 0
        for name in text.split("+"):
            try:
                value |= int(DiagStat[name.strip().upper()])
            except KeyError:
                raise FaultScheduleError(f"fault {item!r}: DIAG_STAT bit {name!r} unknown; one of "
                                         f"{', '.join(b.name for b in DiagStat)}") from None
    if not 0 < value <= 0xFFFF:
        raise FaultScheduleError(f"fault {item!r}: bits must be a non-zero 16-bit DIAG_STAT value")
    return value


def parse_schedule(text: str) -> list[FaultWindow]:
    """Parse a schedule string into windows (raises FaultScheduleError naming the bad item)."""
    windows: list[FaultWindow] = []
    for item in (s.strip() for s in text.split(";")):
        if item:
            windows += _parse_item(item)
    if not windows:
        raise FaultScheduleError("empty fault schedule")
    return windows


def _parse_item(item: str) -> list[FaultWindow]:
    """One KIND@START[-STOP][:OPTIONS] item: its window, or its windows repeated `every` seconds `until`."""
    head, _, opts = item.partition(":")
    kind, start, stop = _parse_head(item, head)
    options, every, until = _parse_options(item, opts)
    if every is None:
        return [FaultWindow(kind, start, stop, options)]
    if stop is None or every <= stop - start:
        raise FaultScheduleError(f"fault {item!r}: every= needs a STOP and a period longer than the window")
    windows = []
    t, n = start, 0
    while t < until:
        windows.append(FaultWindow(kind, t, t + (stop - start), options))
        t, n = start + (n + 1) * every, n + 1
        if n > MAX_WINDOWS:
            raise FaultScheduleError(f"fault {item!r}: more than {MAX_WINDOWS} windows; raise every= or lower until=")
    return windows


def _parse_head(item: str, head: str) -> tuple[FaultKind, float, float | None]:
    """KIND@START[-STOP]: the kind, the start and the stop (None: to the end of the run), s."""
    kind_text, at, span = head.partition("@")
    try:
        kind = FaultKind(kind_text.strip().lower())
    except ValueError:
        raise FaultScheduleError(f"fault {item!r}: kind {kind_text!r} unknown; one of "
                                 f"{', '.join(k.value for k in FaultKind)}") from None
    if not at:
        raise FaultScheduleError(f"fault {item!r}: expected KIND@START[-STOP]")
    start_text, dash, stop_text = span.partition("-")
    start = _float(item, "start", start_text)
    stop = _float(item, "stop", stop_text) if dash else None
    if stop is not None and stop <= start:
        raise FaultScheduleError(f"fault {item!r}: stop {stop:g} s must be after start {start:g} s")
    return kind, start, stop


def _parse_options(item: str, opts: str) -> tuple[dict, float | None, float]:
    """KEY=VALUE,...: the fault's options (p, axis, sign, bits), its repeat period `every` (None: once) and the
    time repeats stop at, `until`."""
    options: dict = {}
    every, until = None, DEFAULT_REPEAT_UNTIL_S
    for opt in filter(None, (o.strip() for o in opts.split(","))):
        key, eq, value = opt.partition("=")
        if not eq:
            raise FaultScheduleError(f"fault {item!r}: option {opt!r} is not KEY=VALUE")
        if key == "p":
            p = _float(item, "p", value)
            if p > 1.0:
                raise FaultScheduleError(f"fault {item!r}: p must be in [0, 1]")
            options["probability"] = p
        elif key == "axis":
            options["axis"] = _axis(item, value)
        elif key == "sign":
            if value not in ("1", "+1", "-1"):
                raise FaultScheduleError(f"fault {item!r}: sign must be +1 or -1")
            options["sign"] = int(value)
        elif key == "bits":
            options["diag_bits"] = _bits(item, value)
        elif key == "every":
            every = _float(item, "every", value)
        elif key == "until":
            until = _float(item, "until", value)
        else:
            raise FaultScheduleError(f"fault {item!r}: option {key!r} unknown (p, axis, sign, bits, every, until)")
    return options, every, until


def build_plan(windows: list[FaultWindow], rate_hz: float, seed: int = 0) -> FaultPlan:
    """A FaultPlan for a chip sampling at `rate_hz` (sample index 0 = when the chip was created)."""
    plan = FaultPlan(seed=seed)
    for w in windows:
        start, stop = w.samples(rate_hz)
        plan.add(w.kind, start_sample=start, stop_sample=stop, **w.options)
    return plan
