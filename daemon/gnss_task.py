"""The daemon's GNSS input: one configured source ([gnss] source), one validator, the aided estimator.

Sources (docs/gnss.md):
* "serial": a receiver on a UART/USB (drivers.gnss.serial_port.SerialGnssSource); its fd is registered with the
  event loop and re-registered when a re-open changes it; `poll_health` once a second;
* "sim": the simulated receiver of the [sensor] scenario writing UBX into a pseudo-terminal
  (drivers.gnss.scenario), read by the same serial source: the hardware path, byte for byte;
* "mavlink": the autopilot's GPS_RAW_INT (GLOBAL_POSITION_INT only as the opt-in fallback), through
  drivers.gnss.mavlink.MavlinkGnssSelector, fed by daemon.inbound;
* "replay": a GNSS recording released in step with the IMU replay, on the recording's time base.

Every fix goes through one drivers.gnss.validation.GnssFixValidator (rejections counted and logged by it),
then to `estimator.update_gnss(fix)` when the estimator is aided (has `update_gnss`). The last accepted
position resolves the declination. Nothing raises out of here: a failing source or estimator call is
counted and logged.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

from ahrsd.core.estimate import EstimateFlags
from ahrsd.core.gnss import GnssFix, GnssFixType
from ahrsd.daemon.local_origin import LocalOrigin
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.drivers.gnss.validation import GnssFixValidator

log = logging.getLogger(__name__)

HEALTH_PERIOD_S = 1.0           # SerialGnssSource.poll_health: "call it about once a second"
REOPEN_PERIOD_S = 2.0           # a port that failed to open is tried again this often (as the source re-opens)
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


def _sim_faults(cfg) -> str:
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
    fixes: int = 0               # fixes the source delivered
    accepted: int = 0            # passed the validator
    rejected: int = 0            # refused by the validator (by reason: validator.counters)
    offered: int = 0             # handed to estimator.update_gnss
    not_used: int = 0            # accepted, but the estimator is not aided
    estimator_errors: int = 0    # update_gnss raised (a bug: counted, logged, the fix dropped)
    source_errors: int = 0       # the source failed to deliver (a read or a recording row)
    gate_warnings: int = 0       # windows in which the estimator's gate rejected most velocities (_watch_gate)


class GnssTask:
    """The GNSS input of one Service (`service.gnss`). `open()` starts the source; the service calls
    `on_mavlink` (inbound), `advance_to` (replay, after each batch of samples) and `tick` (housekeeping)."""

    def __init__(self, service, cfg, *, clock=time.monotonic):
        self.service = service
        self.cfg = cfg
        self.kind = cfg.source
        self.clock = clock
        self.validator = GnssFixValidator(clock=clock, name="gnss")
        self.counters = GnssTaskCounters()
        self.serial = None            # SerialGnssSource (serial, sim)
        self.receiver = None          # the simulated receiver (sim)
        self.selector = None          # MavlinkGnssSelector (mavlink)
        self._replay = None           # iterator of recorded fixes (replay)
        self._replay_next: GnssFix | None = None
        self._serial_args: tuple | None = None
        self.open_error = ""          # why the serial port could not be opened ("" = open or not serial)
        self._next_open = math.inf
        self.replay_finished = False
        self.last_fix: GnssFix | None = None          # last accepted
        self.last_accepted_at: float | None = None    # self.clock() when it was accepted
        self.description = "none"
        self.origin = LocalOrigin()     # LOCAL_POSITION_NED's origin: the first navigation position
        self._fd = -1
        self._next_health = -math.inf
        self._opened_at = math.inf
        self._shown_state = ""
        self._pending_text = ""
        self._last_text_at = -math.inf
        self._gate_window = None        # (start time, offered, rejected velocities) of the estimator's counters

    # ------------------------------------------------------------------------------------------ start / stop
    def open(self) -> None:
        """Start the configured source (raises on a configuration the source refuses: missing device or
        recording), so `ahrsd run` fails at start with the reason."""
        cfg, kind = self.cfg, self.kind
        if kind == "mavlink":
            from ahrsd.drivers.gnss.mavlink import MavlinkGnssSelector

            self.selector = MavlinkGnssSelector(use_fused=cfg.use_fused)
            self.description = "autopilot GPS_RAW_INT" + (" (GLOBAL_POSITION_INT fallback)" if cfg.use_fused else "")
        elif kind == "replay":
            from ahrsd.drivers.gnss.recording import iter_gnss_fixes

            self._replay = iter_gnss_fixes(cfg.file)
            self._replay_next = next(self._replay, None)     # a bad header fails the start, with its reason
            self.replay_finished = self._replay_next is None
            self.description = f"GNSS recording {cfg.file}"
        elif kind in ("serial", "sim"):
            device, baud, protocol, latency = cfg.device, cfg.baud, cfg.protocol, cfg.latency_s
            if kind == "sim":
                from ahrsd.drivers.gnss.scenario import ScenarioGnssReceiver

                sensor = self.service.config.sensor
                outages = ([(cfg.sim_outage_start_s, cfg.sim_outage_start_s + cfg.sim_outage_s,
                             cfg.sim_outage_no_fix)] if cfg.sim_outage_s > 0 else [])
                self.receiver = ScenarioGnssReceiver(
                    sensor.scenario, chip_clock=self.service.source.chip.now, seed=sensor.seed,
                    lever_arm_m=cfg.lever_arm_m, outages=outages, glitch_every_s=cfg.sim_glitch_every_s,
                    glitch_kind=cfg.sim_glitch_kind, glitch_magnitude=cfg.sim_glitch_magnitude or None).start()
                device, baud, protocol, latency = (self.receiver.device, self.receiver.baud, "ubx",
                                                   self.receiver.latency_s)
            self._serial_args = (device, baud, protocol, latency)
            self.description = (f"simulated receiver ({self.service.config.sensor.scenario}, UBX on {device}"
                                f"{_sim_faults(cfg)})"
                                if kind == "sim" else f"receiver on {device} at {baud} baud ({protocol})")
            self._open_serial()
        self._opened_at = self.clock()
        log.info("GNSS: %s", self.description)

    def close(self) -> None:
        self._unregister_reader()
        for part in (self.serial, self.receiver):
            if part is not None:
                try:
                    part.close()
                except Exception:  # noqa: BLE001 - closing must not stop the shutdown
                    log.exception("closing the GNSS source failed")
        close = getattr(self._replay, "close", None)
        if close:
            close()

    # ------------------------------------------------------------------------------------------ the sources
    def _open_serial(self) -> None:
        """Open the port; a receiver missing at start (unplugged, no permission yet) is retried every
        REOPEN_PERIOD_S by `tick`: the IMU must not wait for the GNSS."""
        from ahrsd.drivers.gnss.serial_port import GnssDeviceError, SerialGnssSource

        device, baud, protocol, latency = self._serial_args
        try:
            self.serial = SerialGnssSource(device, baud, protocol, latency_s=latency, clock=self.clock)
        except GnssDeviceError as exc:
            if self.open_error != str(exc):
                log.error("GNSS: %s; retrying every %.0f s", exc, REOPEN_PERIOD_S)
            self.open_error = str(exc)
            self._next_open = self.clock() + REOPEN_PERIOD_S
            return
        if self.open_error:
            log.info("GNSS: %s opened", device)
        self.open_error = ""
        self._register_reader()

    def _register_reader(self) -> None:
        loop = self.service.loop
        fd = self.serial.fileno()
        if fd >= 0 and loop is not None:
            loop.add_reader(fd, self._on_readable)
        self._fd = fd

    def _unregister_reader(self) -> None:
        if self._fd >= 0 and self.service.loop is not None:
            try:
                self.service.loop.remove_reader(self._fd)
            except (ValueError, OSError):
                pass
        self._fd = -1

    def _on_readable(self) -> None:
        try:
            fixes = self.serial.read_available()
        except Exception as exc:  # noqa: BLE001 - documented never to raise; a bug must not stop the loop
            self.counters.source_errors += 1
            log.error("GNSS read failed: %s", exc)
            return
        for fix in fixes:
            self.deliver(fix)
        if self.serial.fileno() != self._fd:      # the device vanished while reading
            self._unregister_reader()
            self._register_reader()

    def on_mavlink(self, msg, now: float) -> None:
        """GPS_RAW_INT / GLOBAL_POSITION_INT from the autopilot, received at monotonic `now`."""
        if self.selector is None:
            return
        try:
            fix = self.selector.handle(msg, now - self.cfg.latency_s)
        except Exception as exc:  # noqa: BLE001 - a hostile message must not reach past the edge
            self.counters.source_errors += 1
            log.warning("GNSS: %s not usable: %s", msg.get_type(), exc)
            return
        if fix is not None:
            self.deliver(fix)

    def advance_to(self, t_s: float) -> None:
        """Replay: deliver every recorded fix valid at or before the IMU replay's time `t_s`."""
        nxt = self._replay_next
        while nxt is not None and nxt.t_s <= t_s:
            self.deliver(nxt)
            try:
                nxt = next(self._replay, None)
            except Exception as exc:  # noqa: BLE001 - GnssRecordingFormatError names file, line and column
                self.counters.source_errors += 1
                log.error("GNSS recording: %s; no more fixes from it", exc)
                self.service.statustext(mavlink.MAV_SEVERITY_ERROR, "ahrsd: GNSS recording unreadable")
                nxt = None
        self._replay_next = nxt
        if nxt is None and not self.replay_finished:
            self.replay_finished = True
            log.info("GNSS recording finished")

    # ------------------------------------------------------------------------------------------ every fix
    def deliver(self, fix) -> None:
        """One fix from the source: validate, then hand it to the aided estimator."""
        c = self.counters
        c.fixes += 1
        rejection = self.validator.check(fix)
        self.service.log_gnss_fix(fix, rejection)      # daemon.vehicle_log: every fix, with its verdict
        if rejection is not None:
            c.rejected += 1
            return
        c.accepted += 1
        first = self.last_fix is None
        self.last_fix, self.last_accepted_at = fix, self.clock()
        estimator = self.service.pipeline.estimator if self.service.pipeline is not None else None
        update_gnss = getattr(estimator, "update_gnss", None)
        if update_gnss is None:
            c.not_used += 1
        else:
            c.offered += 1
            try:
                update_gnss(fix)
            except Exception:  # noqa: BLE001 - the estimator promises not to raise; count it if it does
                c.estimator_errors += 1
                if c.estimator_errors in (1, 100, 10000):
                    log.exception("estimator.update_gnss failed (%d so far)", c.estimator_errors)
        if first:
            log.info("GNSS: first fix %s, %.5f,%.5f", FIX_NAMES.get(fix.fix_type, "?"), fix.lat_deg, fix.lon_deg)
            self.service.on_gnss_position()

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

    def aiding(self) -> str:
        """What the estimator does with GNSS: "aided", "outage", "unaided", or "not used (NAME)"."""
        pipeline = self.service.pipeline
        if pipeline is None or not hasattr(pipeline.estimator, "update_gnss"):
            return f"not used ({getattr(pipeline.estimator, 'name', '?') if pipeline else '?'})"
        est = pipeline.last_estimate
        flags = int(est.flags) if est is not None else 0
        if flags & _GNSS_AIDED:
            return "aided"
        if flags & _GNSS_OUTAGE:
            return "outage"
        return "unaided"

    def _state_key(self, now: float) -> str:
        """What a change is reported for: the link state, the fix type (not the satellite count), the aiding."""
        link = self.serial.state.value if self.serial is not None else ("device_error" if self.open_error else "")
        fix = self.last_fix.fix_type if self.has_fix(now) else None
        return f"{link}/{fix}/{self.aiding()}"

    def fix_summary(self, now: float) -> str:
        """"3D 12 sats", "no fix", or the link state of a serial source that has a problem."""
        if self.open_error:
            return "device error"
        if self.serial is not None and self.serial.state.value not in ("ok", "waiting"):
            return self.serial.state.value.replace("_", " ")
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
        healthy while accepted fixes arrive (and a serial link is not in trouble)."""
        link_ok = not self.open_error and (self.serial is None or self.serial.state.value in ("ok", "waiting"))
        healthy = SENSOR_GPS if self.has_fix(now) and link_ok else 0
        return SENSOR_GPS, SENSOR_GPS, healthy

    def tick(self, now: float) -> None:
        """Housekeeping (10 Hz): link health once a second, reader re-registration, state changes."""
        try:
            if self.serial is None and self._serial_args is not None and now >= self._next_open:
                self._open_serial()
            if self.serial is not None and now >= self._next_health:
                self._next_health = now + HEALTH_PERIOD_S
                self.serial.poll_health()
                if self.serial.fileno() != self._fd:
                    if self.serial.fileno() >= 0:
                        log.info("GNSS device %s re-opened", self.cfg.device or "(sim)")
                    self._unregister_reader()
                    self._register_reader()
            self._report_state(now)
            self._watch_gate(now)
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
            self.service.statustext(severity, self._pending_text)
            self._pending_text, self._last_text_at = "", now

    def _watch_gate(self, now: float) -> None:
        """Over each GATE_WINDOW_S, the share of offered velocities the estimator's innovation gate rejected.
        A filter with a sound attitude rejects correct fixes only when they do not fit the IMU's motion: most
        often an antenna that is not where `[gnss] lever_arm_m` says (it moves as the vehicle rolls), or a wrong
        `latency_s`. Logged and sent as a STATUSTEXT warning, counted in gate_warnings."""
        est = self.service.pipeline.estimator if self.service.pipeline is not None else None
        c = getattr(est, "gnss_counters", None)
        if c is None:
            return
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
            log.warning("the aided filter rejected %d of %d GNSS velocities in the last %.0f s: check [gnss] "
                        "lever_arm_m (%s m, body FRD from the IMU) and latency_s", rejected, offered, now - t0,
                        " ".join(f"{v:g}" for v in self.cfg.lever_arm_m))
            self.service.statustext(mavlink.MAV_SEVERITY_WARNING,
                                    f"ahrsd: GNSS vel rejected {rejected}/{offered}: lever arm?")

    def stats(self) -> dict:
        """Every counter, for `--stats-file` and the tests."""
        out = {**vars(self.counters), "validator": dict(self.validator.counters)}
        if self.serial is not None:
            out["serial"] = dict(self.serial.counters)
        if self.receiver is not None:
            out["sim_receiver"] = self.receiver.counters()
        if self.selector is not None:
            out["mavlink"] = dict(self.selector.counters)
        est = self.service.pipeline.estimator if self.service.pipeline is not None else None
        if hasattr(est, "gnss_counters"):
            out["estimator"] = est.gnss_counters.as_dict()
        return out
