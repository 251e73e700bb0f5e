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
   older than MAX_AGE_S), the published heading starts at the remembered one, follows the vehicle's
   rotation, and reaches the new one by `[outputs] restart_yaw`:
   * "slew": at `restart_slew_deg_s`, a rate chosen so that the lag of the autopilot's yaw behind ours stays
     inside EKF3's gate (below); any autopilot takes it, but learns part of it as gyro bias (overshoot);
   * "reset_counter" (PX4): hold for HOLD_S, long enough for EKF2 to restart EV yaw fusion, then increment
     reset_counter and send the new heading: EKF2 resets its yaw to it at once (ArduPilot: a step);
   * "source_set" (ArduPilot, opted in with `ardupilot_source_set`): hold for HOLD_S, then switch EKF3's
     source set away and back (daemon.source_set_realign): EKF3 re-aligns its yaw to the new heading; if the
     autopilot refuses the switch, slew;
   * "auto" (default): by the autopilot's HEARTBEAT — PX4 → reset_counter; ArduPilot with
     `ardupilot_source_set` → source_set; any other → slew. An autopilot not heard from yet is waited for
     during the hold; `reset_counter_on_calibration = true` keeps choosing reset_counter as before.

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
from ahrsd.daemon.heading_slew import MAX_SLEW_FROM_AGE_S
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.source_set_realign import SourceSetRealign

log = logging.getLogger(__name__)

MEMORY_FILE = "published_heading.json"
SAVE_PERIOD_S = 5.0          # a crash loses at most this much of the vehicle's rotation
MAX_AGE_S = MAX_SLEW_FROM_AGE_S   # older memory: the autopilot has long been on its own yaw; no slew from it
RESTART_STEP_DEG = 1.0       # smaller restart differences are sent as they are
# PX4 restarts EV yaw fusion once samples arrive < 200 ms apart and > 1 s after its last fusion
# (ev_control.cpp, ev_yaw_control.cpp); hold the old heading long enough for that, then reset. An autopilot
# heartbeat (1 Hz) also arrives within it.
HOLD_S = 2.0


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
    sent, `after_publish` with what was sent; `save_now` at shutdown; `on_command_ack` for the autopilot's
    COMMAND_ACKs."""

    def __init__(self, state_dir: Path, slew, *, mode: str = "slew", signal_reset: Callable[[], None],
                 slew_rate_deg_s: float | None = None,
                 autopilot_kind: Callable[[], int | None] = lambda: None,
                 make_realign: Callable[[], SourceSetRealign | None] | None = None,
                 background: Callable[[Callable[[], None]], None] | None = None, clock=time.time):
        self.state_dir = Path(state_dir)
        self.slew = slew
        self.slew_rate_deg_s = slew.max_rate_deg_s if slew_rate_deg_s is None else slew_rate_deg_s
        self.mode = mode
        self.signal_reset = signal_reset
        self.autopilot_kind = autopilot_kind
        self.make_realign = make_realign
        self.background = background or (lambda fn: fn())
        self.clock = clock
        self.memory = load_memory(self.state_dir)
        self.decided = False
        self.restart_step_deg: float | None = None   # measured at the first heading (None: no restart rule)
        self.how: str | None = None                  # what was done: "slew", "reset_counter", "source_set"
        self.realign: SourceSetRealign | None = None
        self._hold_end_s: float | None = None
        self._last_save = -math.inf
        self._last_published: tuple[float, int] | None = None

    @property
    def initial_reset_counter(self) -> int:
        return 0 if self.memory is None else self.memory.reset_counter

    def _resolve(self, final: bool) -> str | None:
        """The mode to use now; None while "auto" still waits for the autopilot (not `final`)."""
        if self.mode != "auto":
            return self.mode
        kind = self.autopilot_kind()
        if kind == mavlink.MAV_AUTOPILOT_PX4:
            return "reset_counter"
        if kind == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA and self.make_realign is not None:
            return "source_set"
        return None if kind is None and not final else "slew"

    def before_publish(self, t_s: float, heading_rad: float) -> None:
        if not self.decided:
            self.decided = True
            self._decide(t_s, heading_rad)
        if self._hold_end_s is not None and t_s >= self._hold_end_s:
            self._hold_end_s = None
            self._after_hold(t_s)
        if self.realign is not None:
            self.realign.tick(t_s)
            if self.realign.gave_up:
                self.realign = None
                self._start_slew()
            elif self.realign.publish_new_heading and self.slew.active:
                self.slew.stop("via source-set switch")   # EKF3 ignores ExtNav yaw now; it aligns on set 1

    def on_command_ack(self, msg) -> None:
        if self.realign is not None:
            self.realign.on_command_ack(msg)

    def _decide(self, t_s: float, heading_rad: float) -> None:
        mem = self.memory
        if mem is None:
            return
        age = self.clock() - mem.wall_time_s
        step = math.degrees(float(wrap_pi(heading_rad - mem.heading_rad)))
        self.restart_step_deg = step
        if abs(step) <= RESTART_STEP_DEG or not 0.0 <= age <= MAX_AGE_S:
            return
        log.info("heading after restart differs by %+.1f° from the one last sent %.0f s ago", step, age)
        reason = f"restart hdg {step:+.0f}°"
        if self._resolve(final=False) != "slew":
            self.slew.start_from(mem.heading_rad, hold_until_s=math.inf, reason=reason)
            self._hold_end_s = t_s + HOLD_S
        else:
            self.slew.start_from(mem.heading_rad, reason=reason)
            self._start_slew()                       # at the restart rate

    def _after_hold(self, t_s: float) -> None:
        mode = self._resolve(final=True)
        if mode == "reset_counter":
            self.how = mode
            self.slew.release(self.slew_rate_deg_s)
            self.signal_reset()                      # reset_counter + 1, the new heading sent as it is
            log.info("restart: held %g s, then reset_counter + 1", HOLD_S)
        elif mode == "source_set" and (realign := self.make_realign() if self.make_realign else None):
            self.how = mode
            self.realign = realign
            realign.start(t_s)
            log.info("restart: held %g s, now switching EKF source sets to re-align the autopilot's yaw", HOLD_S)
        else:
            self._start_slew()

    def _start_slew(self) -> None:
        self.how = "slew"
        self.slew.release(self.slew_rate_deg_s)
        log.info("restart: slewing the heading in at %g deg/s", self.slew_rate_deg_s)

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
