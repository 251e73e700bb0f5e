"""The daemon: one asyncio event loop running the sensor reader, the estimator, the publishers, the MAVLink
receivers and the housekeeping (heartbeat, health, watchdog, status line).

`Service` owns the state and the start/stop; each job lives in its own module as one part of the class:
daemon.sample_reader (reader + per-sample hot path), daemon.publishers (outputs of daemon.output_registry),
daemon.param_protocol (PARAM_*), daemon.inbound (MAVLink input), daemon.declination, daemon.calibration_swap,
daemon.housekeeping.

Extension hooks (used by the field magnetometer calibration, see docs/daemon.md "Extending"):
* `service.commands.register(command_id, handler)` — COMMAND_LONG/INT handlers (`ahrsd.daemon.commands`);
* `service.apply_calibration(cal, save=True)` — persist and swap the calibration between two samples (the
  one path for every calibration change: the estimator re-learns its field reference and the heading sent
  to the autopilot is slewed to the new one);
* `service.add_sample_listener(fn)` — `fn(calibrated_sample, estimate)` after every sample;
* `service.send(msg)`, `service.statustext(severity, text)`, `service.set_calibrating(text)`;
* `service.autopilot` (armed, position, course, speed), `service.params`.
"""

from __future__ import annotations

import asyncio
import logging
import math
import os
import signal
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ahrsd.daemon.heading_slew import HeadingSlew
from ahrsd.calibration.store import CalibrationStore
from ahrsd.daemon import messages as msgs
from ahrsd.daemon.autopilot import AutopilotState
from ahrsd.daemon.builtin_commands import register_builtin_commands
from ahrsd.daemon.calibration_swap import CalibrationSwap
from ahrsd.daemon.commands import CommandRouter
from ahrsd.daemon.config import MAV_TYPES, Config
from ahrsd.daemon.declination import DeclinationResolver
from ahrsd.daemon.endpoint_outputs import EndpointOutputs
from ahrsd.daemon.gnss_task import GnssTask, gnss_backend_for, newest_sample_time, on_first_fix
from ahrsd.daemon.health import Health
from ahrsd.daemon.heading_status import HeadingStatus, LongStatusText
from ahrsd.daemon.housekeeping import Housekeeping
from ahrsd.daemon.inbound import InboundDispatch
from ahrsd.daemon.learned_iron import CMD_LEARNED_IRON, LearnedIron
from ahrsd.daemon.mag_trust import calibration_heading_sigma_rad
from ahrsd.daemon.magcal import attach as attach_magcal
from ahrsd.daemon.mavlink_io import Endpoint, mavlink
from ahrsd.daemon.nmea_output import NmeaOutputs
from ahrsd.daemon.notify import Notifier
from ahrsd.daemon.param_protocol import MOUNTING_PARAMS, ParamProtocol, param_specs
from ahrsd.daemon.params import ParamStore
from ahrsd.daemon.pipeline import Pipeline
from ahrsd.daemon.publishers import Publishers
from ahrsd.daemon.rate_limit import TokenBucket
from ahrsd.daemon.restart_heading import RestartHeading
from ahrsd.daemon.source_set_check import SourceSetCheck
from ahrsd.daemon.source_set_realign import MAV_CMD_SET_EKF_SOURCE_SET, SourceSetRealign
from ahrsd.daemon.sample_reader import SampleReader
from ahrsd.daemon.signing import initial_timestamp, key_fingerprint, load_key, save_timestamp
from ahrsd.daemon.status_line import StatusLine
from ahrsd.daemon.vehicle_log import VehicleLogging
from ahrsd.drivers.source import open_source
from ahrsd.estimator import make_estimator
from ahrsd.estimator.warm_up import warm_up

log = logging.getLogger(__name__)

DEFAULT_SYSTEM_ID = 1                            # until an autopilot heartbeat is latched


@dataclass
class ServiceCounters:
    wakes: int = 0
    overruns: int = 0            # reader wakes that started after their deadline by more than one period
    driver_errors: int = 0       # bus failures (and runs of corrupt frames) that put the sensor in failure
    frame_errors: int = 0        # single corrupt frames rejected by the driver
    unsigned_refused: int = 0    # PARAM_SET refused unsigned (commands are counted by the router)
    published: int = 0
    statustext_suppressed: int = 0  # non-critical STATUSTEXTs dropped by the rate limit (flooding peer)


class Service(SampleReader, Publishers, ParamProtocol, InboundDispatch, DeclinationResolver, CalibrationSwap,
              Housekeeping, EndpointOutputs, VehicleLogging):
    def __init__(self, config: Config, *, source=None, environ=os.environ, stdout=None):
        self.config = config
        self.environ = environ
        self.state_dir: Path = config.state.resolve(environ)
        self.loop: asyncio.AbstractEventLoop | None = None
        self.boot_time = time.monotonic()
        self.health = Health(stale_timeout_s=config.sensor.stale_timeout_s)
        self.autopilot = AutopilotState()
        self.counters = ServiceCounters()
        # STATUSTEXT budget for non-critical texts: 5/s sustained, bursts of 10 (critical ones always go out)
        self._statustext_budget = TokenBucket(rate_per_s=5.0, burst=10)
        self.system_id = config.mavlink.system_id or DEFAULT_SYSTEM_ID
        self.component_id = config.mavlink.component_id
        self.mav_type = MAV_TYPES[config.mavlink.mav_type]
        self.endpoints: list[Endpoint] = []
        self.params = ParamStore(param_specs(config), self.state_dir, on_change=self._on_param_change)
        self.commands = CommandRouter(self, self._send_on, require_signed=lambda: self.signing_required,
                                      accept_broadcast=config.mavlink.accept_broadcast_commands)
        self.notifier = Notifier(environ)
        self.source = source
        self.gnss: GnssTask | None = None      # [gnss] source (daemon.gnss_task), None without one
        self.nmea: NmeaOutputs | None = None    # [[nmea]] outputs (daemon.nmea_output), None without any
        self.pipeline: Pipeline | None = None
        self.heading_status: HeadingStatus | None = None   # the heading state reported (daemon.heading_status)
        self.learned_iron: LearnedIron | None = None       # the iron ins learned, persisted (daemon.learned_iron)
        self.reset_counter = 0
        # the VISION_POSITION_ESTIMATE yaw after a calibration change (apply_calibration)
        self.heading_slew = HeadingSlew(max_rate_deg_s=config.outputs.heading_slew_deg_s)
        self.restart_heading: RestartHeading | None = None   # the restart rule (daemon.restart_heading)
        self.source_set_check: SourceSetCheck | None = None  # may ArduPilot's source set be switched (same)
        self.declination_rad = 0.0
        self.declination_source = "none"
        self.signing_key: bytes | None = None
        self.measured_rate_hz = 0.0
        self.exit_code = 0
        self.ready_sent = False
        self._stdout = stdout if stdout is not None else sys.stdout
        self._status_line: StatusLine | None = None
        self._listeners: list[Callable] = []
        self._stop: asyncio.Event | None = None
        self._last_state: int | None = None
        self._last_decl_update = -math.inf
        self._rate_window: tuple[float, int] = (0.0, 0)
        self._cpu_window: tuple[float, float] = (time.monotonic(), time.process_time())
        self.load_permille = 0
        self._tasks: list[asyncio.Task] = []
        self._consecutive_frame_errors = 0

    # ------------------------------------------------------------------------------------------ public hooks

    @property
    def signing_required(self) -> bool:
        return self.signing_key is not None and self.config.signing.refuse_unsigned_commands

    def send(self, msg, endpoint: Endpoint | None = None) -> None:
        """Send to one endpoint, or to all of them."""
        for ep in (endpoint,) if endpoint is not None else self.endpoints:
            ep.send(msg)

    def statustext(self, severity: int, text: str) -> None:
        """Send a STATUSTEXT to every endpoint. Texts less severe than CRITICAL are rate limited, so a peer
        flooding us with refused requests cannot make us flood the radio with answers (counted, logged)."""
        if severity > mavlink.MAV_SEVERITY_CRITICAL and not self._statustext_budget.take(time.monotonic()):
            self.counters.statustext_suppressed += 1
            log.debug("STATUSTEXT suppressed by the rate limit: %s", text)
            return
        log.log(logging.WARNING if severity <= mavlink.MAV_SEVERITY_WARNING else logging.INFO, "%s", text)
        self.send(msgs.statustext(severity, text))

    def add_sample_listener(self, fn: Callable) -> Callable[[], None]:
        """Call fn(calibrated_sample, estimate) after every sample (keep it cheap). Returns the remover."""
        self._listeners.append(fn)

        def remove() -> None:
            if fn in self._listeners:
                self._listeners.remove(fn)
        return remove

    def set_calibrating(self, what: str) -> None:
        """Report MAV_STATE_CALIBRATING while `what` is non-empty."""
        self.health.calibrating = what

    def request_stop(self, code: int = 0) -> None:
        self.exit_code = code
        if self._stop is not None:
            self._stop.set()

    def link_totals(self) -> dict:
        tx = sum(ep.counters.tx_messages for ep in self.endpoints)
        rx = sum(ep.counters.rx_messages for ep in self.endpoints)
        bad = sum(ep.counters.rx_malformed + ep.counters.rx_bad_signature for ep in self.endpoints)
        return {"tx": tx, "rx": rx, "bad": bad}

    @property
    def recording_time_base(self) -> bool:
        """A replay: outgoing time fields carry the recording's t_s, so a ground station's plot lines up with it."""
        return bool(getattr(self.source, "recording_time_base", False))

    def time_boot_ms(self, now: float | None = None) -> int:
        if self.recording_time_base and self.pipeline is not None and self.pipeline.last_sample is not None:
            return int(self.pipeline.last_sample.t_s * 1000.0) & 0xFFFFFFFF
        return int(((time.monotonic() if now is None else now) - self.boot_time) * 1000.0) & 0xFFFFFFFF

    # ------------------------------------------------------------------------------------------ start / stop

    async def run(self) -> int:
        self.loop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        for sig in (signal.SIGTERM, signal.SIGINT):
            try:
                self.loop.add_signal_handler(sig, self._on_signal, sig)
            except (NotImplementedError, RuntimeError):  # pragma: no cover - non-main thread
                pass
        try:
            self._start()
        except Exception as exc:
            log.error("ahrsd cannot start: %s", exc)
            self._shutdown_io(f"start failed: {exc}")
            return 1
        self._tasks = [self.loop.create_task(self._reader(), name="reader"),
                       self.loop.create_task(self._housekeeping(), name="housekeeping")]
        stop_wait = self.loop.create_task(self._stop.wait())
        done, _ = await asyncio.wait([stop_wait, *self._tasks], return_when=asyncio.FIRST_COMPLETED)
        for task in done:
            if task is not stop_wait and task.exception() is not None:
                log.error("task %s failed", task.get_name(), exc_info=task.exception())
                self.exit_code = 1
        for task in [stop_wait, *self._tasks]:
            task.cancel()
        await asyncio.gather(stop_wait, *self._tasks, return_exceptions=True)
        self._shutdown_io("stopping")
        return self.exit_code

    def _on_signal(self, sig) -> None:
        log.info("received %s, shutting down", signal.Signals(sig).name)
        self.request_stop(0)

    def _start(self) -> None:
        cfg = self.config
        try:
            self.state_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            log.warning("state directory %s unusable (%s): calibration and parameters will not persist",
                        self.state_dir, exc)
        for warning in self.params.load():
            log.warning("%s", warning)
        self.start_restart_rule()
        self._resolve_declination(initial=True)
        calibration = CalibrationStore(self.state_dir).load()
        started = time.monotonic()
        warm_up(cfg.estimator_name)                 # compile before the loop, not on its first sample/fix
        if time.monotonic() - started > 1.0:
            log.info("compiled the %s estimator in %.1f s (cached for the next start)", cfg.estimator_name,
                     time.monotonic() - started)
        mag_sigma_rad = calibration_heading_sigma_rad(calibration)    # how far ins may trust the calibration
        options = dict(cfg.estimator_options)
        if cfg.estimator_name == "ins":
            options["mag_calibration_sigma_rad"] = mag_sigma_rad
        estimator = make_estimator(cfg.estimator_name, declination_rad=self.declination_rad, **options)
        self.pipeline = Pipeline(estimator, calibration)
        self.pipeline.set_mounting([self.params.get(n) for n in MOUNTING_PARAMS])
        self.heading_status = HeadingStatus(LongStatusText(self.send), calibration_sigma_rad=mag_sigma_rad,
                                            good_sigma_rad=math.radians(cfg.daemon.heading_good_sigma_deg))
        self.learned_iron = LearnedIron(
            self.state_dir, self.pipeline, publish=self.params.show, statustext=self.statustext,
            armed=lambda: bool(self.autopilot.armed), background=self._in_background,
            apply_calibration=lambda cal: self.apply_calibration(cal, reason="learned iron accepted"),
            horizontal_field_ut=self._horizontal_field_ut,
            allow_armed=bool(getattr(cfg.magcal, "allow_armed", False)))
        self.learned_iron.restore()
        self._setup_signing()
        for ep_cfg in cfg.endpoints:
            ep = self._make_endpoint(ep_cfg)        # its own output schedule (daemon.endpoint_outputs)
            if self.signing_key is not None:
                ep.enable_signing(self.signing_key, cfg.signing.link_id, initial_timestamp(self.state_dir),
                                  lambda _mav, _msgid: True)   # unsigned input is accepted, then policed
            ep.open(self.loop)
            self.endpoints.append(ep)
            self.check_link_budget(ep)
        self._start_logs()                          # raw samples and MAVLink traffic (daemon.vehicle_log)
        register_builtin_commands(self)
        self.commands.register(CMD_LEARNED_IRON, self.learned_iron.handle_command)
        attach_magcal(self)
        if cfg.nmea:
            self.nmea = NmeaOutputs(cfg.nmea)
            self.nmea.open(self.loop)
            self.add_sample_listener(lambda _sample, est: self.nmea.on_estimate(est))
        if self.source is None:
            self.source = open_source(cfg.sensor, clock=time.monotonic)
        if cfg.gnss.source != "none":
            backend = gnss_backend_for(cfg.gnss, clock=time.monotonic, sensor=cfg.sensor,
                                       scenario_clock=self.source.chip.now if cfg.gnss.source == "sim" else None,
                                       replay_time_s=newest_sample_time(self.pipeline))
            self.gnss = GnssTask(backend, cfg.gnss, clock=time.monotonic, estimator=self.pipeline,
                                 statustext=self.statustext, log_fix=self.log_gnss_fix,
                                 subscribers=[on_first_fix(self.on_gnss_position)],
                                 rejection_cause=self.heading_status.rejection_cause)
            self.gnss.open(self.loop)
        want_line = cfg.daemon.status_line == "on" or (cfg.daemon.status_line == "auto" and self._stdout.isatty())
        self._status_line = StatusLine(self._stdout) if want_line else None
        if self._status_line is not None:
            self._status_line.install_log_filter()
        log.info("ahrsd started: %s, GNSS %s, estimator %s, declination %.2f° (%s), MAVLink %s as %d/%d, state in %s",
                 self.source.description, self.gnss.description if self.gnss else "none", cfg.estimator_name,
                 math.degrees(self.declination_rad),
                 self.declination_source, ", ".join(e.url for e in self.endpoints), self.system_id,
                 self.component_id, self.state_dir)
        self.notifier.status(f"starting: {self.source.description}")
        self._send_heartbeat(time.monotonic())   # routers learn us from our first packet

    def start_restart_rule(self) -> None:
        """Load what the autopilot last got from us (daemon.restart_heading): the reset_counter continues,
        and a different heading after the restart is brought in as `[outputs] restart_yaw` says (slewed, or
        a yaw reset: reset_counter for PX4, an EKF source-set switch for ArduPilot)."""
        out = self.config.outputs
        mode = "reset_counter" if out.restart_yaw == "auto" and out.reset_counter_on_calibration else out.restart_yaw
        make_realign = None
        if out.ardupilot_source_set:
            check = self.source_set_check = SourceSetCheck(out.ardupilot_source_set, lambda m: self.send(m),
                                                           self._autopilot_target)

            def make_realign() -> SourceSetRealign | None:
                if not check.allowed:
                    log.warning("restart: not switching ArduPilot's EKF source set (%s)",
                                check.verdict[1] if check.verdict else "its EK3_SRC parameters not read yet")
                    return None
                return SourceSetRealign(out.ardupilot_source_set, send_command=self._send_source_set_command,
                                        warn_operator=lambda text: self.statustext(mavlink.MAV_SEVERITY_CRITICAL, text))
        self.restart_heading = RestartHeading(
            self.state_dir, self.heading_slew, mode=mode, signal_reset=self.signal_heading_reset,
            slew_rate_deg_s=out.restart_slew_deg_s, autopilot_kind=lambda: self.autopilot.autopilot_kind,
            make_realign=make_realign, background=self._in_background)
        self.reset_counter = self.restart_heading.initial_reset_counter

    def _horizontal_field_ut(self) -> float:
        """WMM's horizontal field at the vehicle (GNSS, autopilot or configured position), NaN without one."""
        from ahrsd.core.wmm import earth_field

        pos = self.gnss.position if self.gnss is not None else None
        if pos is None and self.autopilot.lat_deg is not None:
            pos = (self.autopilot.lat_deg, self.autopilot.lon_deg, self.autopilot.alt_m or 0.0)
        if pos is None and self.config.location.lat_deg is not None:
            pos = (self.config.location.lat_deg, self.config.location.lon_deg, self.config.location.alt_m or 0.0)
        try:
            return earth_field(*pos).horizontal_ut if pos is not None else math.nan
        except ValueError:
            return math.nan

    def _send_source_set_command(self, source_set: int) -> None:
        """MAV_CMD_SET_EKF_SOURCE_SET to the autopilot (daemon.source_set_realign)."""
        self.send(mavlink.MAVLink_command_long_message(*self._autopilot_target(), MAV_CMD_SET_EKF_SOURCE_SET, 0,
                                                       float(source_set), 0, 0, 0, 0, 0, 0))

    def _autopilot_target(self) -> tuple[int, int]:
        return self.autopilot.system_id or self.system_id, self.autopilot.component_id or 1

    def _in_background(self, fn: Callable[[], None]) -> None:
        """Small file writes off the event loop thread (the sample reader must not wait on an fsync)."""
        if self.loop is not None and self.loop.is_running():
            self.loop.run_in_executor(None, fn)
        else:
            fn()

    def _setup_signing(self) -> None:
        if not self.config.signing.key_file:
            return
        self.signing_key = load_key(self.config.signing.key_file)
        log.info("MAVLink signing on (key fingerprint %s)", key_fingerprint(self.signing_key))

    def _shutdown_io(self, why: str) -> None:
        if self._status_line:
            self._status_line.clear()
        self.notifier.stopping(why)
        if self.endpoints:
            self.statustext(mavlink.MAV_SEVERITY_NOTICE, "ahrsd: stopping")
            self.send(msgs.heartbeat(self.mav_type, mavlink.MAV_STATE_POWEROFF))
        if self.signing_key is not None:
            save_timestamp(self.state_dir, max((e.signing_timestamp() for e in self.endpoints), default=0))
        if self.restart_heading is not None:
            self.restart_heading.save_now(self.reset_counter)
        if self.learned_iron is not None:
            self.learned_iron.save_now()
        self._close_logs()                          # after the last frames went out
        for ep in self.endpoints:
            ep.close()
        if self.nmea is not None:
            self.nmea.close()
        if self.gnss is not None:
            self.gnss.close()
        if self.source is not None:
            self.source.close()
        self.notifier.close()

