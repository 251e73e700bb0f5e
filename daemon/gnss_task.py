"""The daemon's GNSS input: one backend ([gnss] source), one validator, the aided estimator, the subscribers.

Every backend (drivers.gnss.backend.GnssBackend: serial receiver, autopilot MAVLink, recording, simulated
receiver) is handled the same way by `poll()`: read the fixes available now, pass each through one
drivers.gnss.validation.GnssFixValidator (rejections counted and logged by it), log it with its verdict, and
hand an accepted fix to the estimator's `update_gnss(fix)` when it is aided, then to every subscriber.
`poll()` runs when the backend's descriptor is readable (given `after_output`: the fixes are read then, and
delivered at the end of the sample reader's next wake, after its outputs were sent), from `tick` (housekeeping),
right after a MAVLink message was offered (`on_mavlink`), and after each batch of replayed samples. Nothing raises out of here: a
failing backend, estimator call or subscriber is counted and logged.

`gnss_backend_for(cfg, ...)` builds the configured backend: the one place that looks at `[gnss] source`.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

from ahrsd.core.estimate import EstimateFlags
from ahrsd.core.gnss import GnssFix, GnssFixType
from ahrsd.daemon.config import GnssConfig, SensorConfig
from ahrsd.daemon.local_origin import LocalOrigin
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.drivers.gnss.backend import GnssBackend, GnssHealth
from ahrsd.drivers.gnss.validation import GnssFixValidator, GnssRejection
from ahrsd.estimator.base import GnssAidedEstimator
from ahrsd.estimator.protocol_check import ProtocolCheck

log = logging.getLogger(__name__)

FIX_STALE_S = 2.0               # no accepted fix for this long: GNSS not healthy (SYS_STATUS), state "no fix"
STATUSTEXT_MIN_INTERVAL_S = 5.0  # GNSS state changes reach the ground station at most this often
GATE_WINDOW_S = 30.0            # the estimator's innovation gate is checked over windows this long
GATE_MIN_OFFERED = 20           # ... holding at least this many fixes
GATE_WARN_FRACTION = 0.3        # ... and it rejected more than this share of their velocities: a STATUSTEXT warning
SENSOR_GPS = mavlink.MAV_SYS_STATUS_SENSOR_GPS
_GNSS_AIDED, _GNSS_OUTAGE = int(EstimateFlags.GNSS_AIDED), int(EstimateFlags.GNSS_OUTAGE)
FIX_NAMES = {GnssFixType.NO_GPS: "no GPS", GnssFixType.NO_FIX: "no fix", GnssFixType.FIX_2D: "2D",
             GnssFixType.FIX_3D: "3D", GnssFixType.DGPS: "DGPS", GnssFixType.RTK_FLOAT: "RTK float",
             GnssFixType.RTK_FIXED: "RTK fixed"}

FixSubscriber = Callable[[GnssFix], None]
FixLog = Callable[[GnssFix, "GnssRejection | None"], None]


class EstimatorHook(Protocol):
    """What the task reads of the per-sample path (daemon.pipeline.Pipeline): the estimator in use now (it
    may be swapped) and its latest estimate (for the aiding flags)."""

    estimator: object

    @property
    def last_estimate(self): ...


def on_first_fix(fn: Callable[[], None]) -> FixSubscriber:
    """A subscriber calling `fn()` once, on the first accepted fix (the declination's GNSS position)."""
    done = False

    def subscriber(fix: GnssFix) -> None:
        nonlocal done
        if not done:
            done = True
            fn()
    return subscriber


def newest_sample_time(pipeline) -> Callable[[], float]:
    """The time of the newest sample the pipeline processed (-inf before the first): a recording's clock."""
    def t_s() -> float:
        sample = pipeline.last_sample
        return sample.t_s if sample is not None else -math.inf
    return t_s


def gnss_backend_for(cfg: GnssConfig, *, clock: Callable[[], float], sensor: SensorConfig | None = None,
                     scenario_clock: Callable[[], float] | None = None,
                     replay_time_s: Callable[[], float] | None = None,
                     sim_writer_thread: bool = True) -> GnssBackend:
    """The backend `cfg.source` names, not started. Each takes its time base explicitly:
    serial, mavlink and sim stamp fixes on `clock` (the samples' clock); sim also needs the simulated
    sensor's `sensor` config and its chip clock `scenario_clock` (the scenario's time, so the receiver
    describes the same motion as the IMU); replay releases a recorded fix once `replay_time_s()` (the newest
    replayed sample's time, `newest_sample_time`) reaches it. sim_writer_thread=False: the simulated receiver
    writes only when stepped (drivers/gnss/sim.py)."""
    kind = cfg.source
    if kind == "serial":
        from ahrsd.drivers.gnss.serial_port import SerialGnssSource

        return SerialGnssSource(cfg.device, cfg.baud, cfg.protocol, latency_s=cfg.latency_s, clock=clock,
                                missing_ok=True)
    if kind == "mavlink":
        from ahrsd.drivers.gnss.mavlink import MavlinkGnssBackend

        return MavlinkGnssBackend(use_fused=cfg.use_fused, latency_s=cfg.latency_s)
    if kind == "replay":
        from ahrsd.drivers.gnss.replay import RecordingGnssBackend

        if replay_time_s is None:
            raise ValueError("[gnss] source = 'replay' needs the replayed samples' time (replay_time_s)")
        return RecordingGnssBackend(cfg.file, replay_time_s)
    if kind == "sim":
        from ahrsd.drivers.gnss.scenario import ScenarioGnssReceiver
        from ahrsd.drivers.gnss.sim import SimulatedGnssBackend

        if sensor is None or scenario_clock is None:
            raise ValueError("[gnss] source = 'sim' needs the simulated sensor's config and chip clock")
        outages = ([(cfg.sim_outage_start_s, cfg.sim_outage_start_s + cfg.sim_outage_s, cfg.sim_outage_no_fix)]
                   if cfg.sim_outage_s > 0 else [])
        receiver = ScenarioGnssReceiver(
            sensor.scenario, chip_clock=scenario_clock, seed=sensor.seed, lever_arm_m=cfg.lever_arm_m,
            outages=outages, glitch_every_s=cfg.sim_glitch_every_s, glitch_kind=cfg.sim_glitch_kind,
            glitch_magnitude=cfg.sim_glitch_magnitude or None)
        return SimulatedGnssBackend(receiver, clock, description=(
            f"simulated receiver ({sensor.scenario}, UBX on {receiver.device}{_sim_faults(cfg)})"),
            writer_thread=sim_writer_thread)
    raise ValueError(f"no GNSS source {kind!r}")


def _sim_faults(cfg: GnssConfig) -> str:
    """The simulated receiver's configured faults, for the log: "; outage 60–90 s; position_jump every 20 s"."""
    out = ""
    if cfg.sim_outage_s > 0:
        out += (f"; outage {cfg.sim_outage_start_s:g}–{cfg.sim_outage_start_s + cfg.sim_outage_s:g} s"
                f"{' (no fix)' if cfg.sim_outage_no_fix else ''}")
    if cfg.sim_glitch_every_s > 0:
        out += f"; {cfg.sim_glitch_kind} every {cfg.sim_glitch_every_s:g} s"
    return out


@dataclass
class GnssTaskCounters:
    fixes: int = 0               # fixes the backend delivered
    accepted: int = 0            # passed the validator
    rejected: int = 0            # refused by the validator (by reason: validator.counters)
    offered: int = 0             # handed to estimator.update_gnss
    not_used: int = 0            # accepted, but the estimator is not aided
    estimator_errors: int = 0    # update_gnss raised (a bug: counted, logged, the fix dropped)
    source_errors: int = 0       # the backend raised from read() or offer() (its own errors are in its stats)
    subscriber_errors: int = 0   # a subscriber raised (counted, logged; the others still get the fix)
    gate_warnings: int = 0       # windows in which the estimator's gate rejected most velocities (_watch_gate)


class GnssTask:
    """The GNSS input of the daemon, for any backend.

    backend: the source (`gnss_backend_for`), not started; `open(loop)` starts it.
    cfg: the [gnss] table (the lever arm, named in the gate warning).
    clock: the samples' monotonic clock (fix age, STATUSTEXT rate).
    estimator: the per-sample path's estimator and latest estimate (EstimatorHook), or None.
    statustext: `statustext(severity, text)` to the ground station.
    log_fix: `log_fix(fix, rejection)` for every fix with its verdict (the vehicle log), or None.
    subscribers: `fn(fix)` for every accepted fix, after the estimator.
    rejection_cause: `rejection_cause(now, lever_arm_explains)` -> the cause of rejected velocities when it is not the lever arm
    (daemon.heading_status: a heading the magnetometer made wrong), or None.
    """

    def __init__(self, backend: GnssBackend, cfg: GnssConfig, *, clock: Callable[[], float],
                 estimator: EstimatorHook | None, statustext: Callable[[int, str], None],
                 log_fix: FixLog | None = None, subscribers: Sequence[FixSubscriber] = (),
                 rejection_cause: Callable[[float, bool], str | None] | None = None):
        self.backend = backend
        self.cfg = cfg
        self.clock = clock
        self.estimator = estimator
        self.statustext = statustext
        self.log_fix = log_fix
        self.subscribers = list(subscribers)
        self.rejection_cause = rejection_cause
        self.validator = GnssFixValidator(clock=clock, name="gnss")
        self.counters = GnssTaskCounters()
        self.last_fix: GnssFix | None = None          # last accepted
        self.last_accepted_at: float | None = None    # self.clock() when it was accepted
        self.origin = LocalOrigin()     # LOCAL_POSITION_NED's origin: the first navigation position
        self._loop = None
        self._fd = -1
        self._after_output = None       # open(after_output=): where a readable descriptor's fixes wait to be delivered
        self._pending: list[GnssFix] = []   # read and stamped, waiting for the reader's outputs (_on_readable)
        self._delivery_deferred = False
        self._opened_at = math.inf
        self._shown_state = ""
        self._pending_text = ""
        self._last_text_at = -math.inf
        self._gate_window = None        # (start time, offered, rejected velocities) of the estimator's counters
        self._fitted_arm_shown = None   # the fitted antenna arm last announced (_watch_fitted_arm)
        self._is_aided = ProtocolCheck(GnssAidedEstimator)    # asked at every tick and fix of the same estimator

    @property
    def description(self) -> str:
        return self.backend.description

    # ------------------------------------------------------------------------------------------ start / stop
    def open(self, loop=None, after_output: Callable[[Callable[[], None]], None] | None = None) -> None:
        """Start the backend (raises on a configuration it refuses, so `ahrsd run` fails at start with the
        reason) and watch its descriptor on `loop` when it has one. `after_output(fn)`: runs `fn` once after the
        next outputs are sent (daemon.sample_reader SampleReader.after_output); given, a readable descriptor's
        fixes are read and delivered then, not in front of an output that is due (`_on_readable`)."""
        self.backend.start()
        self._loop = loop
        self._after_output = after_output
        self._follow_fd()
        self._opened_at = self.clock()
        log.info("GNSS: %s", self.description)

    def close(self) -> None:
        self._unwatch_fd()
        try:
            self.backend.close()
        except Exception:  # noqa: BLE001 - closing must not stop the shutdown
            log.exception("closing the GNSS source failed")

    @property
    def polled_when_readable(self) -> bool:
        """The event loop polls this source whenever its descriptor is readable (a receiver on a serial port or
        pty): nothing else needs to poll it to get its fixes in time."""
        return self._fd >= 0

    def _follow_fd(self) -> None:
        """(Re-)register the backend's descriptor when it changed (a receiver re-opened after a loss)."""
        fd = self.backend.fileno()
        if fd == self._fd:
            return
        self._unwatch_fd()
        if fd >= 0 and self._loop is not None:
            self._loop.add_reader(fd, self._on_readable)
            self._fd = fd

    def _unwatch_fd(self) -> None:
        if self._fd >= 0 and self._loop is not None:
            try:
                self._loop.remove_reader(self._fd)
            except (ValueError, OSError):
                pass
        self._fd = -1

    def _on_readable(self) -> None:
        """The backend's descriptor is readable. Without `after_output`: poll now. With it: the bytes are read and
        the fixes they complete decoded and stamped now (a serial fix's stamp comes from its arrival time,
        drivers/gnss/receiver_time.py: a late read would bias it), and their delivery (the validator, the log, the
        aided filter's update and the subscribers: milliseconds of the loop, docs/daemon.md "Performance") waits for
        the end of the reader's next wake, so it does not sit between a block handed over and its outputs (#28's
        p99). The housekeeping tick delivers them too when it polls first: a stalled reader delays a fix by one
        tick at most."""
        if self._after_output is None:
            self.poll()
            return
        fixes = self._read()            # now: each fix stamped at its arrival
        self._follow_fd()
        if fixes:
            self._pending += fixes
            if not self._delivery_deferred:
                self._delivery_deferred = True
                self._after_output(self._deliver_pending)

    def _deliver_pending(self) -> None:
        self._delivery_deferred = False
        pending, self._pending = self._pending, []
        for fix in pending:
            self.deliver(fix)

    # ------------------------------------------------------------------------------------------ the one loop
    def on_mavlink(self, msg, now: float) -> None:
        """A GPS_RAW_INT / GLOBAL_POSITION_INT from the autopilot, received at `now`: offered to the backend
        (only the MAVLink backend takes fixes from it), then polled."""
        try:
            self.backend.offer(msg, now)
        except Exception as exc:  # noqa: BLE001 - the backend promises not to raise; count it if it does
            self.counters.source_errors += 1
            log.error("GNSS backend failed on a MAVLink message: %s", exc)
        self.poll()

    def poll(self) -> int:
        """Read the backend and deliver every fix (after those read before and still waiting, `_on_readable`);
        returns how many it delivered."""
        fixes = self._read()
        if self._pending:
            fixes, self._pending = self._pending + fixes, []
        for fix in fixes:
            self.deliver(fix)
        self._follow_fd()
        return len(fixes)

    def _read(self) -> list[GnssFix]:
        try:
            return self.backend.read()
        except Exception as exc:  # noqa: BLE001 - read() promises not to raise; a bug must not stop the loop
            self.counters.source_errors += 1
            log.error("GNSS read failed: %s", exc)
            return []

    def deliver(self, fix) -> None:
        """One fix from the backend: validate, log, then the aided estimator and the subscribers."""
        c = self.counters
        c.fixes += 1
        rejection = self.validator.check(fix)
        if self.log_fix is not None:
            self.log_fix(fix, rejection)
        if rejection is not None:
            c.rejected += 1
            return
        c.accepted += 1
        first = self.last_fix is None
        self.last_fix, self.last_accepted_at = fix, self.clock()
        estimator = self._aided_estimator()
        if estimator is None:
            c.not_used += 1
        else:
            c.offered += 1
            try:
                estimator.update_gnss(fix)
            except Exception:  # noqa: BLE001 - the estimator promises not to raise; count it if it does
                c.estimator_errors += 1
                if c.estimator_errors in (1, 100, 10000):
                    log.exception("estimator.update_gnss failed (%d so far)", c.estimator_errors)
        if first:
            log.info("GNSS: first fix %s, %.5f,%.5f", FIX_NAMES.get(fix.fix_type, "?"), fix.lat_deg, fix.lon_deg)
        for subscriber in self.subscribers:
            try:
                subscriber(fix)
            except Exception:  # noqa: BLE001 - one faulty subscriber must not starve the others
                c.subscriber_errors += 1
                if c.subscriber_errors in (1, 100, 10000):
                    log.exception("a GNSS fix subscriber failed (%d so far)", c.subscriber_errors)

    def _aided_estimator(self) -> GnssAidedEstimator | None:
        est = self.estimator.estimator if self.estimator is not None else None
        return est if self._is_aided(est) else None

    # ------------------------------------------------------------------------------------------ state
    @property
    def position(self) -> tuple[float, float, float] | None:
        """(lat_deg, lon_deg, alt_m) of the last accepted fix with a position, for the declination."""
        f = self.last_fix
        if f is None or not f.has_position:
            return None
        return f.lat_deg, f.lon_deg, (f.alt_m if math.isfinite(f.alt_m) else 0.0)

    def has_fix(self, now: float) -> bool:
        return self.last_accepted_at is not None and now - self.last_accepted_at <= FIX_STALE_S

    def health(self) -> GnssHealth:
        return self.backend.health()

    def aiding(self) -> str:
        """What the estimator does with GNSS: "aided", "outage", "unaided", or "not used (NAME)"."""
        if self._aided_estimator() is None:
            est = self.estimator.estimator if self.estimator is not None else None
            return f"not used ({est.name if est is not None else '?'})"
        est = self.estimator.last_estimate
        flags = int(est.flags) if est is not None else 0
        if flags & _GNSS_AIDED:
            return "aided"
        if flags & _GNSS_OUTAGE:
            return "outage"
        return "unaided"

    def _state_key(self, now: float) -> str:
        """What a change is reported for: the link state, the fix type (not the satellite count), the aiding."""
        fix = self.last_fix.fix_type if self.has_fix(now) else None
        return f"{self.health().state.value}/{fix}/{self.aiding()}"

    def fix_summary(self, now: float) -> str:
        """"3D 12 sats", "no fix", or the link state of a backend that has a problem ("device error")."""
        link = self.health().state
        if not link.usable:
            return link.value.replace("_", " ")
        if not self.has_fix(now):
            return "no fix"
        f = self.last_fix
        sats = f" {f.num_sats} sats" if f.num_sats >= 0 else ""
        return f"{FIX_NAMES.get(f.fix_type, '?')}{sats}"

    def status(self, now: float) -> str:
        """One phrase for the status line and STATUSTEXT: "GNSS 3D 12 sats, aided"."""
        return f"GNSS {self.fix_summary(now)}, {self.aiding()}"

    def sensor_bits(self, now: float) -> tuple[int, int, int]:
        """MAV_SYS_STATUS_SENSOR_GPS as (present, enabled, healthy): present and enabled with a source,
        healthy while accepted fixes arrive and the link is not in trouble."""
        healthy = SENSOR_GPS if self.has_fix(now) and self.health().state.usable else 0
        return SENSOR_GPS, SENSOR_GPS, healthy

    def tick(self, now: float) -> None:
        """Housekeeping (10 Hz): poll (a backend without a descriptor, a lost device's re-open), report
        state changes, watch the estimator's gate."""
        try:
            self.poll()
            self._report_state(now)
            self._watch_gate(now)
            self._watch_fitted_arm()
        except Exception:  # noqa: BLE001 - housekeeping carries on whatever the GNSS source does
            self.counters.source_errors += 1
            log.exception("GNSS housekeeping failed")

    def _report_state(self, now: float) -> None:
        """A STATUSTEXT when the GNSS state changes, at most every STATUSTEXT_MIN_INTERVAL_S (the latest state
        wins when it flaps faster)."""
        if self.last_fix is None and now - self._opened_at < FIX_STALE_S:
            return                              # starting: the receiver has not had the time to send a fix
        state = self._state_key(now)
        if state != self._shown_state:
            self._shown_state = state
            self._pending_text = f"ahrsd: {self.status(now)}"
        if self._pending_text and now - self._last_text_at >= STATUSTEXT_MIN_INTERVAL_S:
            healthy = self.has_fix(now)
            severity = mavlink.MAV_SEVERITY_INFO if healthy else mavlink.MAV_SEVERITY_WARNING
            self.statustext(severity, self._pending_text)
            self._pending_text, self._last_text_at = "", now

    def _watch_gate(self, now: float) -> None:
        """Over each GATE_WINDOW_S, the share of offered velocities the estimator's innovation gate rejected.
        A filter with a sound attitude rejects correct fixes only when they do not fit the IMU's motion: most
        often an antenna that is not where `[gnss] lever_arm_m` says (it moves as the vehicle rolls), or a wrong
        `latency_s`. Logged and sent as a STATUSTEXT warning, counted in gate_warnings."""
        est = self._aided_estimator()
        if est is None:
            return
        c = est.gnss_counters
        if self._gate_window is None:
            self._gate_window = (now, c.offered, c.rejected_velocity)
            return
        t0, offered0, rejected0 = self._gate_window
        if now - t0 < GATE_WINDOW_S:
            return
        offered, rejected = c.offered - offered0, c.rejected_velocity - rejected0
        self._gate_window = (now, c.offered, c.rejected_velocity)
        if offered >= GATE_MIN_OFFERED and rejected > GATE_WARN_FRACTION * offered:
            self.counters.gate_warnings += 1
            fit = est.lever_arm_fit()
            # the latch, as the heading reads it: the arm in use (told, or the fitted one adopted) not yet shown right
            explains = fit is not None and fit.heading_bent
            cause = self.rejection_cause(now, explains) if self.rejection_cause is not None else None
            if cause is not None:
                log.warning("the aided filter rejected %d of %d GNSS velocities in the last %.0f s: %s",
                            rejected, offered, now - t0, cause)
                self.statustext(mavlink.MAV_SEVERITY_WARNING, f"ahrsd: GNSS vel rejected {rejected}/{offered}: {cause}")
                return
            told = " ".join(f"{v:g}" for v in self.cfg.lever_arm_m)
            if explains:
                # the lever-arm check (estimator/lever_arm_fit.py) found where the innovations put the antenna
                at = fit.antenna_m(self.cfg.lever_arm_m).tolist()
                log.warning("the aided filter rejected %d of %d GNSS velocities in the last %.0f s: they fit an "
                            "antenna at %s m (body FRD from the IMU), not at [gnss] lever_arm_m %s m: measure it "
                            "and set lever_arm_m", rejected, offered, now - t0, " ".join(f"{v:.1f}" for v in at),
                            told)
                self.statustext(mavlink.MAV_SEVERITY_WARNING,     # ≤ 50 characters: a STATUSTEXT's text
                                f"ahrsd: GNSS vel rej {rejected}/{offered}: arm {','.join(f'{v:.1f}' for v in at)}?")
                return
            log.warning("the aided filter rejected %d of %d GNSS velocities in the last %.0f s: check [gnss] "
                        "lever_arm_m (%s m, body FRD from the IMU) and latency_s", rejected, offered, now - t0, told)
            self.statustext(mavlink.MAV_SEVERITY_WARNING, f"ahrsd: GNSS vel rejected {rejected}/{offered}: lever arm?")

    def _watch_fitted_arm(self) -> None:
        """The arm the aided filter fuses with once its lever-arm check adopted a fitted one (the told arm plus the
        fitted error, estimator/lever_arm_fit.py): logged and sent as a STATUSTEXT warning each time it changes by
        0.1 m. The told arm stays the operator's: nothing is written to the config."""
        est = self._aided_estimator()
        # the adopted correction alone: the fit (lever_arm_fit()) is made only when asked, and asking at every
        # tick would make it after every fix
        adopted_m = est.lever_arm_adopted_m() if est is not None else None
        if adopted_m is None:
            return
        # the arm in use (told + adopted), not the latest fit's: that moves with every fix while it is refitted
        at = tuple(round(float(t) + float(a), 1) + 0.0 for t, a in zip(self.cfg.lever_arm_m, adopted_m))
        if at == self._fitted_arm_shown:
            return
        self._fitted_arm_shown = at
        text = ",".join(f"{v:.1f}" for v in at)
        log.warning("GNSS arm %s m fitted: set gnss.lever_arm_m (it says %s m, body FRD from the IMU; the aided "
                    "filter fuses at the fitted arm until restarted)", text,
                    " ".join(f"{v:g}" for v in self.cfg.lever_arm_m))
        # ≤ 50 characters: a STATUSTEXT's text (longer is sent in chunks)
        self.statustext(mavlink.MAV_SEVERITY_WARNING, f"ahrsd: GNSS arm {text} m fitted: set it")

    def stats(self) -> dict:
        """Every counter, for `--stats-file` and the tests: the task's, the validator's (by reason), the
        backend's groups ("serial", "mavlink", "recording", "sim_receiver") and the aided estimator's."""
        out = {**vars(self.counters), "validator": dict(self.validator.counters)}
        try:
            out.update(self.backend.stats())
        except Exception:  # noqa: BLE001 - the stats file must not fail for one backend's counters
            log.exception("GNSS backend stats failed")
        est = self._aided_estimator()
        if est is not None:
            out["estimator"] = est.gnss_counters.as_dict()
        return out
