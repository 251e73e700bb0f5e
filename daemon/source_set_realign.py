"""An instant re-alignment of ArduPilot EKF3's yaw to ours, by switching its EKF source set away and back.

EKF3 has no command that resets its yaw to an external-navigation heading, and `reset_counter` is a position
reset only (docs/daemon.md "Restarts"). What does re-align it is a change of yaw source: SelectMagFusion
(libraries/AP_NavEKF3/AP_NavEKF3_MagFusion.cpp) sets `yaw_source_reset` whenever the active yaw source
differs from the last one, and with the source back on ExternalNav the next ExtNav yaw it takes is applied
by `alignYawAngle` (a reset of the yaw and its variance, "EKF3 IMUn yaw aligned"), not fused through the gate.
MAV_CMD_SET_EKF_SOURCE_SET (42007, param1 = set 1..3; GCS_Common.cpp, AP_NavEKF_Source::setPosVelYawSourceSet)
switches the active set.

So, with the operator's opt-in (`[outputs] ardupilot_source_set`, an alternate set identical to set 1 except
for its yaw source, which must not be ExternalNav):
1. while the autopilot still gets the heading it had (held by the caller), switch to the alternate set;
2. once it acknowledges, publish the new heading: EKF3 ignores ExtNav yaw while its yaw source is not
   ExternalNav;
3. SWITCH_BACK_S later — longer than VISO_DELAY_MS (≤ 250 ms) plus the link, so the sample EKF3 recalls at its
   fusion horizon is already the new heading — switch back to set 1: EKF3 aligns its yaw to the new heading.
A refused or unanswered first switch gives up before anything changed (the caller slews instead); the switch
back is retried, and if it is never acknowledged the operator is told, loudly, to switch back by hand.
"""

from __future__ import annotations

import logging
import math
from typing import Callable

from ahrsd.daemon.mavlink_io import mavlink

log = logging.getLogger(__name__)

MAV_CMD_SET_EKF_SOURCE_SET = 42007
PRIMARY_SOURCE_SET = 1
SWITCH_BACK_S = 0.5          # > VISO_DELAY_MS max (250 ms) + link latency
ACK_TIMEOUT_S = 1.0
SWITCH_BACK_ATTEMPTS = 3


class SourceSetRealign:
    """The sequence above, driven by `tick(t_s)` at every published heading (sample time) and
    `on_command_ack(msg)`. `send_command(source_set)` sends MAV_CMD_SET_EKF_SOURCE_SET to the autopilot;
    `warn_operator(text)` reaches the ground station."""

    IDLE, SWITCHING_AWAY, ON_ALTERNATE, SWITCHING_BACK, DONE, FAILED = range(6)

    def __init__(self, alternate_set: int, send_command: Callable[[int], None],
                 warn_operator: Callable[[str], None]):
        if alternate_set not in (2, 3):
            raise ValueError(f"alternate EKF source set must be 2 or 3, not {alternate_set}")
        self.alternate_set = alternate_set
        self.send_command = send_command
        self.warn_operator = warn_operator
        self.state = self.IDLE
        self._deadline_s = math.inf
        self._switch_back_at_s = math.inf
        self._acked: int | None = None           # MAV_RESULT of the outstanding command, once answered
        self._attempts = 0

    @property
    def publish_new_heading(self) -> bool:
        """True once the autopilot is on the alternate set: the caller stops holding the old heading."""
        return self.state in (self.ON_ALTERNATE, self.SWITCHING_BACK, self.DONE)

    @property
    def gave_up(self) -> bool:
        """The first switch was refused or unanswered: nothing changed; the caller slews instead."""
        return self.state == self.FAILED

    def start(self, t_s: float) -> None:
        self.state = self.SWITCHING_AWAY
        self._send(t_s, self.alternate_set)

    def on_command_ack(self, msg) -> None:
        if msg.command == MAV_CMD_SET_EKF_SOURCE_SET and self.state in (self.SWITCHING_AWAY, self.SWITCHING_BACK):
            self._acked = msg.result

    def tick(self, t_s: float) -> None:
        if self.state == self.SWITCHING_AWAY:
            if self._acked == mavlink.MAV_RESULT_ACCEPTED:
                self.state = self.ON_ALTERNATE
                self._switch_back_at_s = t_s + SWITCH_BACK_S
            elif self._acked is not None or t_s >= self._deadline_s:
                why = "no answer" if self._acked is None else f"result {self._acked}"
                log.warning("MAV_CMD_SET_EKF_SOURCE_SET %d refused (%s): slewing the heading in instead",
                            self.alternate_set, why)
                self.state = self.FAILED
        elif self.state == self.ON_ALTERNATE and t_s >= self._switch_back_at_s:
            self.state = self.SWITCHING_BACK
            self._send(t_s, PRIMARY_SOURCE_SET)
        elif self.state == self.SWITCHING_BACK:
            if self._acked == mavlink.MAV_RESULT_ACCEPTED:
                self.state = self.DONE
                log.info("EKF source set %d → %d: ArduPilot re-aligns its yaw to ours", self.alternate_set,
                         PRIMARY_SOURCE_SET)
            elif self._acked is not None or t_s >= self._deadline_s:
                if self._attempts < SWITCH_BACK_ATTEMPTS:
                    self._send(t_s, PRIMARY_SOURCE_SET)
                else:
                    self.state = self.DONE
                    self.warn_operator(f"ahrsd: EKF may still be on source set {self.alternate_set}")
                    log.error("the autopilot did not confirm MAV_CMD_SET_EKF_SOURCE_SET 1 after %d attempts: it "
                              "may still be on source set %d (switch it back)", self._attempts, self.alternate_set)

    def _send(self, t_s: float, source_set: int) -> None:
        self._acked = None
        self._deadline_s = t_s + ACK_TIMEOUT_S
        self._attempts = self._attempts + 1 if source_set == PRIMARY_SOURCE_SET else 0
        self.send_command(source_set)
