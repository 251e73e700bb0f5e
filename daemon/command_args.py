"""One view of a command's parameters for COMMAND_LONG and COMMAND_INT, and the input checks every command
handler makes before it acts.

MAVLink carries a MAV_CMD in either message (common.xml COMMAND_LONG / COMMAND_INT):

| view      | COMMAND_LONG  | COMMAND_INT                                             |
|-----------|---------------|---------------------------------------------------------|
| param1..4 | param1..4     | param1..4 (float)                                       |
| param5/6  | param5/6      | x/y (int32: latitude/longitude in degE7 for positions)  |
| param7    | param7        | z (float)                                               |

Handlers read `CommandArgs.of(msg)` instead of the message fields, so no handler can ask a COMMAND_INT for a
`param7` it does not have. A refused request is returned as `Refused(result, reason)`: the router counts it,
logs one rate-limited warning and ACKs the result.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ahrsd.daemon.mavlink_io import mavlink

DEG_E7 = 1e-7           # COMMAND_INT x/y positions: degrees × 10^7
# the MAV_FRAMEs in which COMMAND_INT x/y are a latitude/longitude (common.xml MAV_FRAME: the GLOBAL_* ones)
GLOBAL_FRAMES = frozenset(v for v, e in mavlink.enums["MAV_FRAME"].items() if e.name.startswith("MAV_FRAME_GLOBAL"))


class Refused(int):
    """A request refused at the edge: the MAV_RESULT to answer (it is that int, so a handler's callers that
    compare results keep working) and `reason`, one line saying why."""

    reason: str

    def __new__(cls, result: int, reason: str) -> "Refused":
        obj = super().__new__(cls, int(result))
        obj.reason = reason
        return obj

    @property
    def result(self) -> int:
        return int(self)


@dataclass(frozen=True)
class CommandArgs:
    command: int
    is_command_int: bool
    params: tuple[float, ...]        # param1..param7 as in the table above (x/y as floats of the int32)
    x: int = 0                       # COMMAND_INT only (0 for COMMAND_LONG)
    y: int = 0
    frame: int = 0                   # COMMAND_INT's MAV_FRAME (0 = MAV_FRAME_GLOBAL for COMMAND_LONG)

    @classmethod
    def of(cls, msg) -> "CommandArgs":
        if msg.get_type() == "COMMAND_INT":
            return cls(int(msg.command), True,
                       (msg.param1, msg.param2, msg.param3, msg.param4, float(msg.x), float(msg.y), msg.z),
                       int(msg.x), int(msg.y), int(msg.frame))
        return cls(int(msg.command), False,
                   (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7))

    def p(self, n: int) -> float:
        """param<n>, 1-based as in the MAVLink command tables."""
        return self.params[n - 1]

    def int_position_deg(self) -> tuple[float, float] | None:
        """COMMAND_INT's x/y as latitude/longitude in degrees (degE7); None when not a COMMAND_INT or both 0.
        Raises nothing; check `position_frame_ok` before trusting it."""
        if not self.is_command_int or (self.x == 0 and self.y == 0):
            return None
        return self.x * DEG_E7, self.y * DEG_E7

    @property
    def position_frame_ok(self) -> bool:
        """The frame makes x/y a latitude/longitude (a GLOBAL_* MAV_FRAME)."""
        return self.frame in GLOBAL_FRAMES


def whole_number(value: float, lo: int, hi: int) -> int | None:
    """`value` as an int when it is a finite whole number in [lo, hi], else None (never raises: int(nan) would)."""
    if not math.isfinite(value) or value != math.floor(value) or not lo <= value <= hi:
        return None
    return int(value)


def all_finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def position_problem(lat_deg: float, lon_deg: float) -> str | None:
    """None for a usable latitude/longitude, else why not."""
    if not all_finite(lat_deg, lon_deg):
        return f"position {lat_deg}, {lon_deg} is not finite"
    if not -90.0 <= lat_deg <= 90.0:
        return f"latitude {lat_deg:g} deg outside [-90, 90]"
    if not -180.0 <= lon_deg <= 180.0:
        return f"longitude {lon_deg:g} deg outside [-180, 180]"
    return None
