"""A restart the autopilot can tell from a heading step: what the autopilot last got from us is kept in the
state directory, and a restart with a different heading is brought in like a calibration change.

What the autopilots do with VISION_POSITION_ESTIMATE after a gap (read from their source):
* ArduPilot EKF3: `reset_counter` only stamps a reset time (AP_VisualOdom_Backend::get_reset_timestamp_ms),
  which writeExtNavData (AP_NavEKF3_Measurements.cpp) turns into `posReset`, used only to reset the NE
  position when ExtNav is the position source (AP_NavEKF3_PosVelFusion.cpp). Nothing resets yaw: when our
  data returns, EKF3 fuses the new yaw through its innovation gate (AP_NavEKF3_MagFusion.cpp, fuseEulerYaw),
  which in flight rejects a step beyond ~3σ for good.
* PX4 EKF2: vision fusion stops 400 ms after our data stops (ev_control.cpp, 2·EV_MAX_INTERVAL). A changed
  `reset_counter` resets EKF2's yaw to ours only while EV yaw fusion is running (ev_yaw_control.cpp,
  `ev_reset` branch); when fusion (re)starts, the first sample is fused through the heading gate
  (EKF2_HDG_GATE · σ, σ² ≥ EKF2_EVA_NOISE), so a large step right after a restart is never taken.

The rule (docs/daemon.md, "Restarts"):
1. `reset_counter` persists: a restart continues with the value the autopilot last saw (no spurious reset).
2. The last published heading is saved every SAVE_PERIOD_S and on shutdown. If, at the first heading after
   a restart, the estimator's heading differs from it by more than RESTART_STEP_DEG (and the memory is no
   older than MAX_AGE_S), the published heading starts at the remembered one and
   * default: slews to the new one at `[outputs] restart_slew_deg_s`, a rate chosen so that the lag of
     the autopilot's yaw behind ours stays inside EKF3's gate (below);
   * with `reset_counter_on_calibration = true` (PX4): holds the remembered heading (following the
     vehicle's rotation) for RESET_HOLD_S, long enough for EKF2 to restart EV yaw fusion, then increments
     reset_counter and sends the new heading: EKF2 resets its yaw to it at once. (ArduPilot would see
     that as a step: use the default with ArduPilot.)

Why a slew is accepted: EKF3 (AP_NavEKF3_MagFusion.cpp, fuseEulerYaw) rejects an ExtNav yaw in flight
when innov² > (EK3_YAW_I_GATE/100)² · (H·P·Hᵀ + R), R = max(angErr, 5°)² (writeExtNavData) with angErr
clamped to [VISO_YAW_M_NSE, 1.5 rad] (AP_VisualOdom_MAV.cpp). The innovation is our yaw minus EKF3's, so
what the gate sees during a slew is how far EKF3's yaw lags behind ours, not our per-message step. A ramp
of r makes that lag grow to r · T_lag; restart_slew_deg_s keeps it below the smallest gate, 3 · 5°.
"""

from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ahrsd.calibration.atomic_file import write_atomic
from ahrsd.core.angles import wrap_pi

log = logging.getLogger(__name__)

MEMORY_FILE = "published_heading.json"
SAVE_PERIOD_S = 5.0          # a crash loses at most this much of the vehicle's rotation
MAX_AGE_S = 600.0            # older memory: the autopilot has long been on its own yaw; no slew from it
RESTART_STEP_DEG = 1.0       # smaller restart differences are sent as they are
# PX4 restarts EV yaw fusion once samples arrive < 200 ms apart and > 1 s after its last fusion
# (ev_control.cpp, ev_yaw_control.cpp); hold the old heading long enough for that, then reset
RESET_HOLD_S = 2.0


@dataclass(frozen=True)
class RememberedHeading:
    heading_rad: float       # the last VISION_POSITION_ESTIMATE yaw we sent (true north)
    reset_counter: int
    wall_time_s: float       # when it was saved (time.time: the monotonic clock restarts with the host)


def load_memory(state_dir: Path) -> RememberedHeading | None:
    path = Path(state_dir) / MEMORY_FILE
    try:
        d = json.loads(path.read_text())
        mem = RememberedHeading(float(d["heading_rad"]), int(d["reset_counter"]) & 0xFF, float(d["wall_time_s"]))
    except FileNotFoundError:
        return None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        log.warning("ignoring %s: %s", path, exc)
        return None
    if not (math.isfinite(mem.heading_rad) and math.isfinite(mem.wall_time_s)):
        log.warning("ignoring %s: not finite", path)
        return None
    return mem


class RestartHeading:
    """The restart rule above, for the VISION_POSITION_ESTIMATE builder: `before_publish` at every heading
    sent, `after_publish` with what was sent; `save_now` at shutdown."""

    def __init__(self, state_dir: Path, slew, *, reset_mode: bool, signal_reset: Callable[[], None],
                 slew_rate_deg_s: float | None = None,
                 background: Callable[[Callable[[], None]], None] | None = None, clock=time.time):
        self.state_dir = Path(state_dir)
        self.slew = slew
        self.slew_rate_deg_s = slew.max_rate_deg_s if slew_rate_deg_s is None else slew_rate_deg_s
        self.reset_mode = reset_mode
        self.signal_reset = signal_reset
        self.background = background or (lambda fn: fn())
        self.clock = clock
        self.memory = load_memory(self.state_dir)
        self.decided = False
        self.restart_step_deg: float | None = None   # measured at the first heading (None: no restart rule)
        self._reset_at_s: float | None = None
        self._last_save = -math.inf
        self._last_published: tuple[float, int] | None = None

    @property
    def initial_reset_counter(self) -> int:
        return 0 if self.memory is None else self.memory.reset_counter

    def before_publish(self, t_s: float, heading_rad: float) -> None:
        if not self.decided:
            self.decided = True
            self._decide(t_s, heading_rad)
        if self._reset_at_s is not None and t_s >= self._reset_at_s:
            self._reset_at_s = None
            self.signal_reset()

    def _decide(self, t_s: float, heading_rad: float) -> None:
        mem = self.memory
        if mem is None:
            return
        age = self.clock() - mem.wall_time_s
        step = math.degrees(float(wrap_pi(heading_rad - mem.heading_rad)))
        self.restart_step_deg = step
        if abs(step) <= RESTART_STEP_DEG or not 0.0 <= age <= MAX_AGE_S:
            return
        if self.reset_mode:
            self.slew.start_from(mem.heading_rad, hold_until_s=t_s + RESET_HOLD_S)
            self._reset_at_s = t_s + RESET_HOLD_S
            how = f"held {RESET_HOLD_S:g} s, then reset_counter + 1"
        else:
            self.slew.start_from(mem.heading_rad, rate_deg_s=self.slew_rate_deg_s)
            how = f"slewed at {self.slew_rate_deg_s:g} deg/s"
        log.info("heading after restart differs by %+.1f° from the one last sent %.0f s ago: %s",
                 step, age, how)

    def after_publish(self, yaw_rad: float, reset_counter: int) -> None:
        self._last_published = (yaw_rad, reset_counter)
        now = self.clock()
        if now - self._last_save >= SAVE_PERIOD_S:
            self._last_save = now
            data = self._payload(now)
            self.background(lambda: self._write(data))

    def save_now(self, reset_counter: int) -> None:
        """At shutdown: the last heading sent and the reset_counter in force."""
        if self._last_published is None:
            if self.memory is None:
                return
            # nothing sent this run: keep what the autopilot last got, with the counter in force
            self._last_published = (self.memory.heading_rad, reset_counter)
            now = self.memory.wall_time_s
        else:
            self._last_published = (self._last_published[0], reset_counter)
            now = self.clock()
        self._write(self._payload(now))

    def _payload(self, now: float) -> bytes:
        yaw, counter = self._last_published
        return json.dumps({"heading_rad": yaw, "reset_counter": counter & 0xFF, "wall_time_s": now}).encode()

    def _write(self, data: bytes) -> None:
        try:
            write_atomic(self.state_dir / MEMORY_FILE, data, mode=0o644)
        except OSError as exc:
            log.warning("cannot save the published heading: %s", exc)
