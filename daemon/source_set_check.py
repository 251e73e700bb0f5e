"""Before ahrsd may switch ArduPilot's EKF source set (daemon.source_set_realign), it reads the sets from the
autopilot and checks that the switch changes nothing but the yaw source.

For the 0.5 s on the alternate set EKF3 uses that set's position and velocity sources; if they differ from set
1's, EKF3 resets its position or velocity to the new source (AP_NavEKF3_Control.cpp, setAidingMode: a change of
source sets `posxy_source_reset` / `velxy_source_reset`), and a set left at its defaults (AP_NavEKF_Source.cpp:
POSXY, VELXY, VELZ and YAW None, POSZ Baro) has no horizontal source.
So the sets are read with PARAM_REQUEST_READ and the switch is allowed only when EK3_SRC1_YAW is ExternalNav
(6), the alternate set's yaw is not, and its POSXY, VELXY, POSZ and VELZ equal set 1's. Until the answers are
in (requested again at each autopilot HEARTBEAT, a few times), the switch is not allowed: the restart slews.
"""

from __future__ import annotations

import logging
import math
from typing import Callable

from ahrsd.daemon.mavlink_io import mavlink

log = logging.getLogger(__name__)

EXTNAV = 6
AXES = ("POSXY", "VELXY", "POSZ", "VELZ", "YAW")
MAX_REQUESTS = 5          # rounds of requests (one per autopilot HEARTBEAT) before giving up


def param_name(source_set: int, axis: str) -> str:
    return f"EK3_SRC{source_set}_{axis}"


class SourceSetCheck:
    """`on_autopilot_heartbeat()` at each ArduPilot HEARTBEAT, `on_param_value(msg)` for its PARAM_VALUEs;
    `verdict` is None until decided, then (allowed, why). `send(msg)` reaches the autopilot `target`."""

    def __init__(self, alternate_set: int, send: Callable[[object], None], target: Callable[[], tuple[int, int]]):
        self.alternate_set = alternate_set
        self.send = send
        self.target = target
        self.names = [param_name(s, a) for s in (1, alternate_set) for a in AXES]
        self.values: dict[str, float] = {}
        self.requests = 0
        self.verdict: tuple[bool, str] | None = None

    @property
    def allowed(self) -> bool:
        return self.verdict is not None and self.verdict[0]

    def on_autopilot_heartbeat(self) -> None:
        if self.verdict is not None:
            return
        if self.requests >= MAX_REQUESTS:
            missing = [n for n in self.names if n not in self.values]
            self._decide(False, f"no answer for {', '.join(missing)}")
            return
        self.requests += 1
        system, component = self.target()
        for name in self.names:
            if name not in self.values:
                self.send(mavlink.MAVLink_param_request_read_message(system, component, name.encode(), -1))

    def on_param_value(self, msg) -> None:
        name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode(errors="replace")
        name = name.rstrip("\x00")
        if self.verdict is not None or name not in self.names or not math.isfinite(msg.param_value):
            return
        self.values[name] = msg.param_value
        if len(self.values) == len(self.names):
            self._decide(*self._judge())

    def _judge(self) -> tuple[bool, str]:
        v, alt = self.values, self.alternate_set
        if v[param_name(1, "YAW")] != EXTNAV:
            return False, f"EK3_SRC1_YAW is {v[param_name(1, 'YAW')]:g}, not 6 (ExternalNav)"
        if v[param_name(alt, "YAW")] == EXTNAV:
            return False, f"EK3_SRC{alt}_YAW is 6 too: switching sets would not change the yaw source"
        differ = [a for a in AXES[:-1] if v[param_name(alt, a)] != v[param_name(1, a)]]
        if differ:
            return False, "EK3_SRC{}_{{{}}} differ from set 1 (EKF3 would reset position/velocity)".format(
                alt, ",".join(differ))
        return True, f"EK3_SRC{alt}_* equal set 1 except the yaw ({v[param_name(alt, 'YAW')]:g})"

    def _decide(self, allowed: bool, why: str) -> None:
        self.verdict = (allowed, why)
        if allowed:
            log.info("ArduPilot source set %d may be used to re-align EKF3's yaw after a restart: %s",
                     self.alternate_set, why)
        else:
            log.warning("ArduPilot source set %d will NOT be used to re-align EKF3's yaw (a restart with another "
                        "heading is slewed in): %s", self.alternate_set, why)
