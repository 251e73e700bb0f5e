"""The daemon: one asyncio event loop running the sensor reader, the estimator, the publishers, the MAVLink
receivers and the housekeeping (heartbeat, health, watchdog, status line).

`Service` is the composition root: it builds the parts (docs/architecture.md), hands each the others it
needs, starts them and stops them. It holds no behaviour of its own beyond that wiring, the parameter
changes (which part a parameter belongs to) and the few values the outputs read (`OutputContext`).

Parts: daemon.outbound (endpoints, send, STATUSTEXT), daemon.endpoint_outputs (per-endpoint schedules),
daemon.sample_reader (reader + per-sample hot path), daemon.publishers (outputs of daemon.output_registry),
daemon.inbound (MAVLink input), daemon.param_protocol (PARAM_*), daemon.position + daemon.declination,
daemon.calibration_swap, daemon.heading_resets, daemon.housekeeping, daemon.vehicle_log, daemon.gnss_task,
daemon.magcal (field calibration), daemon.builtin_commands, daemon.heading_status (the heading state reported),
daemon.learned_iron (the iron ins learned, persisted).

The hooks other code uses (docs/daemon.md "Extending"): `service.commands.register(command_id, handler)`,
`service.apply_calibration(cal, save=True)`, `service.add_sample_listener(fn)`, `service.send(msg)`,
`service.statustext(severity, text)`, `service.set_calibrating(text)`, `service.autopilot`, `service.params`.
"""

from __future__ import annotations

import asyncio
import logging
import math
import os
import signal
import sys
import time
from pathlib import Path
from typing import Callable

from ahrsd.calibration.store import CalibrationStore
from ahrsd.daemon import messages as msgs
from ahrsd.daemon.autopilot import AutopilotState
from ahrsd.daemon.builtin_commands import BuiltinCommands
from ahrsd.daemon.calibration_swap import CalibrationSwap
from ahrsd.daemon.commands import CommandAck, CommandRouter
from ahrsd.daemon.config import MAV_TYPES, Config
from ahrsd.daemon.counters import ServiceCounters
from ahrsd.daemon.declination import Declination
from ahrsd.daemon.endpoint_outputs import EndpointOutputs
from ahrsd.daemon.gnss_task import GnssTask, gnss_backend_for, newest_sample_time, on_first_fix
from ahrsd.daemon.gyro_cal import GyroBiasCalibration
from ahrsd.daemon.heading_resets import HeadingResets
from ahrsd.daemon.heading_slew import HeadingSlew
from ahrsd.daemon.health import Health
from ahrsd.daemon.heading_status import HeadingStatus
from ahrsd.daemon.housekeeping import Every, HealthReport, Housekeeping
from ahrsd.daemon.inbound import InboundDispatch
from ahrsd.daemon.learned_iron import ACTION_PARAM as LEARNED_IRON_ACTION
from ahrsd.daemon.learned_iron import CMD_LEARNED_IRON, LearnedIron
from ahrsd.calibration.heading_trust import (calibration_frame_tilt_heading_sigma_rad, calibration_frame_tilt_sigma_rad,
                                             calibration_heading_sigma_rad, has_mag_calibration)
from ahrsd.calibration.accel_trust import calibration_accel_bias_sigma_m_s2
from ahrsd.daemon.magcal import DaemonMagCalHost, FieldCalibrationPart, MagCalProtocol
from ahrsd.daemon.magcal_settings import MagCalSettings
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.nmea_output import NmeaOutputs
from ahrsd.daemon.notify import Notifier, watchdog_interval_s
from ahrsd.daemon.outbound import Identity, Outbound
from ahrsd.daemon.output_registry import BY_PARAM_NAME, OUTPUTS
from ahrsd.daemon.param_protocol import MOUNTING_PARAMS, ParamProtocol, param_specs
from ahrsd.daemon.params import ParamError, ParamStore
from ahrsd.daemon.pipeline import Pipeline
from ahrsd.daemon.position import PositionResolver
from ahrsd.daemon.position_memory import PositionMemory
from ahrsd.daemon.publishers import Publishers
from ahrsd.daemon.restart_heading import RestartHeading
from ahrsd.daemon.run_stats import sample_accounting
from ahrsd.daemon.sample_reader import ReaderOutputs, SampleListeners, SampleReader
from ahrsd.daemon.signing import initial_timestamp, key_fingerprint, load_key, save_timestamp
from ahrsd.daemon.source_set_check import SourceSetCheck
from ahrsd.daemon.source_set_realign import MAV_CMD_SET_EKF_SOURCE_SET, SourceSetRealign
from ahrsd.daemon.status_line import StatusLine, format_status
from ahrsd.daemon.vehicle_log import VehicleLogs
from ahrsd.drivers.source import SensorSource, open_source
from ahrsd.daemon.broadcast_notice import BroadcastNotice
from ahrsd.estimator import make_estimator
from ahrsd.daemon.estimator_news import estimator_news_muted
from ahrsd.estimator.base import (Estimator, FieldCircleCheckedEstimator, HeadingCheckedEstimator,
                                  MagCalibrationAwareEstimator, AccelCalibrationAwareEstimator,
                                  MagFrameTiltAwareEstimator)
from ahrsd.estimator.protocol_check import ProtocolCheck
from ahrsd.estimator.warm_up import warm_up

log = logging.getLogger(__name__)

DEFAULT_SYSTEM_ID = 1                            # until an autopilot heartbeat is latched
STATUS_LINE_PERIOD_S = 0.5
SIGNING_SAVE_PERIOD_S = 30.0
VISION_POSITION_ESTIMATE = mavlink.MAVLINK_MSG_ID_VISION_POSITION_ESTIMATE


class Service:
    def __init__(self, config: Config, *, source: SensorSource | None = None, environ=os.environ, stdout=None,
                 clock: Callable[[], float] = time.monotonic, warm_fit_worker: bool = True):
        """The parts that exist from construction on, in named steps and this order: the service's own state, the
        MAVLink core (`_build_mavlink_core`), the heading and position parts (`_build_heading_and_position`),
        the outputs' parts (`_build_output_parts`); the parts built at start are declared None
        (`_declare_parts_built_at_start`, built by `start`)."""
        self.config = config
        # the daemon's one clock (CLOCK_MONOTONIC, the event loop's and the sensor source's): every rate limit and
        # timeout of the parts reads it; a test steps it
        self.clock = clock
        self._warm_fit_worker = warm_fit_worker    # the field calibration's (daemon.magcal.MagCalProtocol)
        self.environ = environ
        self.state_dir: Path = config.state.resolve(environ)
        self.loop: asyncio.AbstractEventLoop | None = None
        self.boot_time = clock()
        self.source = source
        self.exit_code = 0
        self.signing_key: bytes | None = None
        self._stdout = stdout if stdout is not None else sys.stdout
        self._stop: asyncio.Event | None = None
        self._tasks: list[asyncio.Task] = []
        # what the estimator is, asked at every housekeeping tick: worked out again only for another estimator
        self._heading_checked = ProtocolCheck(HeadingCheckedEstimator)
        self._circle_checked = ProtocolCheck(FieldCircleCheckedEstimator)
        self._build_mavlink_core(config, environ, clock)
        self._build_heading_and_position(config, environ, clock)
        self._build_output_parts()
        self._declare_parts_built_at_start()

    def _build_mavlink_core(self, config: Config, environ, clock: Callable[[], float]) -> None:
        """Health, the autopilot's state, the counters, the outbound side (identity, endpoints, STATUSTEXT), the
        parameters, the command router, the service manager's notifier and the sample listeners."""
        self.health = Health(stale_timeout_s=config.sensor.stale_timeout_s)
        self.autopilot = AutopilotState()
        self.counters = ServiceCounters()
        self.outbound = Outbound(Identity(config.mavlink.system_id or DEFAULT_SYSTEM_ID,
                                          config.mavlink.component_id, MAV_TYPES[config.mavlink.mav_type]),
                                 self.counters, clock=clock)
        self.params = ParamStore(param_specs(config), self.state_dir, on_change=self._on_param_change)
        self.commands = CommandRouter(lambda endpoint, msg: endpoint.send(msg),
                                      require_signed=lambda: self.signing_required,
                                      statustext=self.outbound.statustext,
                                      accept_broadcast=config.mavlink.accept_broadcast_commands,
                                      broadcast_notice=BroadcastNotice(self.outbound.statustext,
                                                                       config.mavlink.component_id),
                                      clock=clock)
        self.notifier = Notifier(environ)
        self.listeners = SampleListeners()

    def _build_heading_and_position(self, config: Config, environ, clock: Callable[[], float]) -> None:
        """The VISION_POSITION_ESTIMATE yaw after a calibration change and its reset_counter, the GNSS and NMEA
        slots (filled at start when configured), the position resolver, the declination and the vehicle logs."""
        self.heading = HeadingResets(HeadingSlew(max_rate_deg_s=config.outputs.heading_slew_deg_s),
                                     statustext=self.outbound.statustext)
        self.gnss: GnssTask | None = None      # [gnss] source (daemon.gnss_task), None without one
        self.nmea: NmeaOutputs | None = None    # [[nmea]] outputs (daemon.nmea_output), None without any
        # the last real position, kept across restarts; a simulated or replayed run's positions are not the vehicle's
        memory = PositionMemory(self.state_dir, record=config.sensor.source in ("spi", "iio"),
                                background=self._in_background)
        self.positions = PositionResolver(config.location, gnss_position=self._gnss_position,
                                          autopilot=self.autopilot, simulator=config.sensor.source == "sim",
                                          memory=memory)
        self.autopilot.add_gnss_listener(lambda msg: self.positions.note_live_position())
        self.declination = Declination(self.params, self.positions, signal_reset=self.heading.signal, clock=clock)
        self.logs = VehicleLogs(config.log, state_dir=self.state_dir, environ=environ,
                                gnss_source=config.gnss.source, recording_time_base=config.sensor.source == "replay")

    def _build_output_parts(self) -> None:
        """The per-endpoint output schedules (SR_* base rates, signing) and the parameter protocol."""
        self.endpoint_outputs = EndpointOutputs(
            self.outbound, base_rates_hz=lambda: {o.message_id: self.params.get(o.param_name) for o in OUTPUTS},
            signed=lambda: self.signing_key is not None, warn_soon=self._statustext_soon)
        self.param_protocol = ParamProtocol(self.params, self.outbound, self.counters,
                                            signing_required=lambda: self.signing_required,
                                            spawn=lambda coro: self.loop.create_task(coro))

    def _declare_parts_built_at_start(self) -> None:
        """The parts `start` builds (they need the state directory's contents, the pipeline, the endpoints or the
        source), None until then."""
        self.restart_heading: RestartHeading | None = None   # the restart rule (daemon.restart_heading)
        self.source_set_check: SourceSetCheck | None = None  # may ArduPilot's source set be switched (same)
        self.pipeline: Pipeline | None = None
        self.swap: CalibrationSwap | None = None
        self.publishers: Publishers | None = None
        self.inbound: InboundDispatch | None = None
        self.field_calibration: FieldCalibrationPart | None = None
        self.reader: SampleReader | None = None
        self.health_report: HealthReport | None = None
        self.status_line: StatusLine | None = None
        self.heading_status: HeadingStatus | None = None   # the heading state reported (daemon.heading_status)
        self.learned_iron: LearnedIron | None = None       # the iron ins learned, persisted (daemon.learned_iron)

    # ------------------------------------------------------------------------------------------ public hooks

    @property
    def signing_required(self) -> bool:
        return self.signing_key is not None and self.config.signing.refuse_unsigned_commands

    @property
    def endpoints(self):
        return self.outbound.endpoints

    @property
    def system_id(self) -> int:
        return self.outbound.identity.system_id

    @property
    def component_id(self) -> int:
        return self.outbound.identity.component_id

    @property
    def reset_counter(self) -> int:
        return self.heading.reset_counter

    @property
    def heading_slew(self) -> HeadingSlew:
        return self.heading.slew

    @property
    def calibration(self):
        return self.pipeline.calibration

    @property
    def magcal(self) -> MagCalProtocol | None:
        """The field calibration's protocol handler (None before start)."""
        return None if self.field_calibration is None else self.field_calibration.protocol

    def send(self, msg, endpoint=None) -> None:
        self.outbound.send(msg, endpoint)

    def statustext(self, severity: int, text: str) -> None:
        self.outbound.statustext(severity, text)

    def add_sample_listener(self, fn: Callable, *, in_place: bool = False) -> Callable[[], None]:
        """Call fn(calibrated_sample, estimate) after every sample (keep it cheap; daemon.sample_reader.
        SampleListeners says what `in_place` gives). Returns the remover."""
        return self.listeners.add(fn, in_place=in_place)

    def apply_calibration(self, cal, *, save: bool = True, reason: str = "") -> None:
        """The one path for every calibration change (daemon.calibration_swap)."""
        self.swap.apply(cal, save=save, reason=reason)

    def set_calibrating(self, what: str) -> None:
        """Report MAV_STATE_CALIBRATING while `what` is non-empty."""
        self.health.calibrating = what

    def signal_heading_reset(self) -> None:
        self.heading.signal()

    def request_stop(self, code: int = 0) -> None:
        self.exit_code = code
        if self._stop is not None:
            self._stop.set()

    def link_totals(self) -> dict:
        return self.outbound.link_totals()

    # ------------------------------------------------------------------------------------------ OutputContext

    @property
    def declination_rad(self) -> float:
        return self.declination.rad

    @property
    def recording_time_base(self) -> bool:
        """A replay: outgoing time fields carry the recording's t_s, so a ground station's plot lines up with it."""
        return self.source is not None and self.source.recording_time_base

    def time_boot_ms(self, now: float | None = None) -> int:
        if self.recording_time_base and self.pipeline is not None and self.pipeline.last_sample is not None:
            return int(self.pipeline.last_sample.t_s * 1000.0) & 0xFFFFFFFF
        return int(((self.clock() if now is None else now) - self.boot_time) * 1000.0) & 0xFFFFFFFF

    def sample_time_monotonic(self, t_s: float) -> float:
        """The time a message carries for a sample stamped t_s: CLOCK_MONOTONIC (the chip source stamps in
        that clock already); a replay keeps the recording's t_s (`recording_time_base`)."""
        if self.recording_time_base:
            return t_s
        return t_s + (self.source.monotonic_offset_s if self.source is not None else 0.0)

    def heading_trusted(self, now: float) -> bool:
        return self.health.heading_trusted(now)

    def autopilot_yaw(self, est) -> tuple[float, int, float]:
        # a reset of ins's yaw to the GNSS yaw is slewed into the yaw it publishes (its σ covering what is left:
        # estimator/published_heading.py): no step reaches the autopilot, so reset_counter is not incremented
        return self.heading.autopilot_yaw(est)

    def autopilot_yaw_withheld(self, est) -> None:
        self.heading.withheld(est)

    def _yaw_resets(self) -> tuple[int, int]:
        """(yaw resets, of which planned GNSS-yaw alignments): ins counts them; mekf has none."""
        est = self.pipeline.estimator
        if not self._heading_checked(est):
            return 0, 0
        return int(est.yaw_resets), int(est.gnss_yaw_alignments)

    def _field_circle(self):
        """The estimator's check of the calibration by the field's circle in turns (mekf, ins before its first fix;
        estimator/field_circle.py), None where there is none."""
        est = self.pipeline.estimator
        return est.field_circle() if self._circle_checked(est) else None

    def local_origin(self):
        return None if self.gnss is None else self.gnss.origin

    def sys_status_message(self, now: float):
        present, enabled, healthy = self.health.sensor_bits(now)
        if self.gnss is not None:
            present, enabled, healthy = (a | b for a, b in zip((present, enabled, healthy),
                                                                self.gnss.sensor_bits(now)))
        unsigned = self.commands.counters.unsigned_refused + self.counters.unsigned_refused
        acc = sample_accounting(self)             # missed, late, corrupt (+ bus failures) samples
        load = self.health_report.load_permille if self.health_report is not None else 0
        return msgs.sys_status(present, enabled, healthy, load, self.outbound.comm_errors(),
                               (unsigned, acc["missed"], acc["late"], acc["corrupt"] + self.counters.driver_errors))

    def build_output(self, mid: int, now: float):
        return self.publishers.build_output(mid, now)

    # ------------------------------------------------------------------------------------------ GNSS

    def _gnss_position(self):
        return None if self.gnss is None else self.gnss.position

    # ------------------------------------------------------------------------------------------ parameters

    def _on_param_change(self, name: str, value: float) -> None:
        """What a parameter change does (raises ParamError to refuse it)."""
        if name.startswith("SR_"):
            try:    # every endpoint following the daemon-wide rate
                self.endpoint_outputs.set_output_rate_hz(BY_PARAM_NAME[name].message_id, value)
            except ValueError as exc:
                raise ParamError(f"{name}: {exc}") from None
        elif name.startswith("MNT_"):
            if self.pipeline is not None:
                rpy = [self.params.get(n) for n in MOUNTING_PARAMS]
                rpy[MOUNTING_PARAMS.index(name)] = value
                self.pipeline.set_mounting(rpy)
                self.heading.signal()
                if self.learned_iron is not None:
                    self.learned_iron.calibration_changed()   # a body-frame iron belongs to its mounting
        elif name in ("DECL_MANUAL", "DECL_DEG"):
            self.loop.call_soon(self.declination.resolve)
        elif name == LEARNED_IRON_ACTION and self.learned_iron is not None:
            self.learned_iron.on_param(value)          # 1 accept, 2 reset (daemon.learned_iron)

    def _statustext_soon(self, severity: int, text: str) -> None:
        if self.loop is not None:
            self.loop.call_soon(self.outbound.statustext, severity, text)

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
            self.start()
        except Exception as exc:
            log.error("ahrsd cannot start: %s", exc)
            self.shutdown_io(f"start failed: {exc}")
            return 1
        self._tasks = [self.loop.create_task(self.reader.run(self.loop), name="reader"),
                       self.loop.create_task(self._housekeeping().run(self.loop), name="housekeeping")]
        stop_wait = self.loop.create_task(self._stop.wait())
        done, _ = await asyncio.wait([stop_wait, *self._tasks], return_when=asyncio.FIRST_COMPLETED)
        for task in done:
            if task is not stop_wait and task.exception() is not None:
                log.error("task %s failed", task.get_name(), exc_info=task.exception())
                self.exit_code = 1
        for task in [stop_wait, *self._tasks]:
            task.cancel()
        await asyncio.gather(stop_wait, *self._tasks, return_exceptions=True)
        self.shutdown_io("stopping")
        return self.exit_code

    def _on_signal(self, sig) -> None:
        """SIGINT/SIGTERM: stop, said once. A terminal's Ctrl-C and `timeout`'s group signal reach the daemon
        twice under `script` or a shell; the second changes nothing and is not logged again."""
        if self._stop is not None and self._stop.is_set():
            return
        log.info("received %s, shutting down", signal.Signals(sig).name)
        self.request_stop(0)

    def start(self) -> None:
        """Build the parts that need the pipeline, the endpoints or the source, and open them, in this order:
        the state (directory, parameters, restart rule, declination), the pipeline with its estimator, the
        heading parts, the MAVLink endpoints and the logs, the field calibration and the NMEA outputs, the
        sensor source, the commands, the GNSS task, the inbound dispatch and the reader's outputs, and last
        the status line, the start-up log line and the first heartbeat."""
        self._load_state()
        calibration = CalibrationStore(self.state_dir).load()
        self._compile_estimator()
        estimator = self._make_estimator()
        mag_sigma_rad = self._tell_calibration(estimator, calibration)    # before its first sample: built with it
        self.use_pipeline(Pipeline(estimator, calibration))
        self.pipeline.set_mounting([self.params.get(n) for n in MOUNTING_PARAMS])
        self._start_heading_parts(mag_sigma_rad)
        self._setup_signing()
        self._open_endpoints()
        self.logs.start(self.pipeline.calibration, self.outbound.endpoints)   # raw samples and MAVLink traffic
        self._start_field_calibration()
        self._open_nmea()
        if self.source is None:
            self.source = open_source(self.config.sensor, clock=self.clock)
        self._register_builtin_commands()
        self._open_gnss()
        self.inbound = self.build_inbound()
        self.reader.source = self.source
        self.reader.outputs.raw_sink = self.logs.put_sample
        self._start_status_line()
        self._announce_start()

    def _load_state(self) -> None:
        """The state directory (a warning when unusable: nothing persists), the parameters saved in it, the
        restart rule and the declination at start."""
        try:
            self.state_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            log.warning("state directory %s unusable (%s): calibration and parameters will not persist",
                        self.state_dir, exc)
        for warning in self.params.load():
            log.warning("%s", warning)
        self.start_restart_rule()
        self.declination.resolve(initial=True)

    def _compile_estimator(self) -> None:
        """Compile the estimator before the loop, not on its first sample/fix."""
        name = self.config.estimator_name
        started = time.monotonic()      # host clock: how long the compile took, for the log
        with estimator_news_muted():
            warm_up(name)
        took_s = time.monotonic() - started     # host clock: (same)
        if took_s > 1.0:
            log.info("compiled the %s estimator in %.1f s (cached for the next start)", name, took_s)

    def _make_estimator(self) -> Estimator:
        """The configured estimator at the declination (told the calibration next, before its first sample: it
        is then the estimator built with it)."""
        cfg = self.config
        return make_estimator(cfg.estimator_name, declination_rad=self.declination.rad, **cfg.estimator_options)

    @staticmethod
    def _tell_calibration(estimator: Estimator, calibration) -> float:
        """Tell the estimator what a calibration leaves (at start, and after every change): its predicted heading
        error (NaN: unknown; mekf and ins: without GNSS the published yaw σ carries it, and their heading checks
        start again on it: estimator/calibration_heading.py), the tilt of its frame (ins's frame-tilt states'
        prior, estimator/mag_frame_tilt.py), then the accelerometer bias (mekf: the published tilt σ carries it,
        calibration/accel_trust.py). Returns that heading error, the one figure the heading
        status takes too (computed here only)."""
        mag_sigma_rad = calibration_heading_sigma_rad(calibration)
        if isinstance(estimator, MagCalibrationAwareEstimator):
            estimator.set_mag_calibration_sigma(mag_sigma_rad)
        if isinstance(estimator, MagFrameTiltAwareEstimator):
            estimator.set_mag_calibration_frame_tilt_sigma(calibration_frame_tilt_sigma_rad(calibration),
                                                           calibration_frame_tilt_heading_sigma_rad(calibration))
        if isinstance(estimator, AccelCalibrationAwareEstimator):
            estimator.set_accel_bias_sigma(calibration_accel_bias_sigma_m_s2(calibration))
        return mag_sigma_rad

    def _start_heading_parts(self, mag_sigma_rad: float) -> None:
        """The heading status reported (daemon.heading_status) and the learned iron restored and its command
        registered (daemon.learned_iron)."""
        cfg = self.config
        self.heading_status = HeadingStatus(self.outbound.statustext, calibration_sigma_rad=mag_sigma_rad,
                                            calibration_in_force=has_mag_calibration(self.pipeline.calibration),
                                            good_sigma_rad=math.radians(cfg.outputs.heading_good_sigma_deg))
        self.learned_iron = LearnedIron(
            self.state_dir, self.pipeline, publish=self.params.show, statustext=self.outbound.statustext,
            armed=lambda: bool(self.autopilot.armed), background=self._in_background,
            apply_calibration=lambda cal: self.apply_calibration(cal, reason="learned iron accepted"),
            horizontal_field_ut=self._horizontal_field_ut,
            allow_armed=(cfg.magcal or MagCalSettings()).allow_armed)
        self.learned_iron.restore()
        self.commands.register(CMD_LEARNED_IRON, self.learned_iron.handle_command)

    def _open_endpoints(self) -> None:
        """Every configured MAVLink endpoint, with its own output schedule (daemon.endpoint_outputs), signed
        when there is a key, opened and its link budget checked."""
        cfg = self.config
        for ep_cfg in cfg.endpoints:
            ep = self.endpoint_outputs.make_endpoint(ep_cfg, self._on_message)
            if self.signing_key is not None:
                ep.enable_signing(self.signing_key, cfg.signing.link_id, initial_timestamp(self.state_dir),
                                  lambda _mav, _msgid: True)   # unsigned input is accepted, then policed
            ep.open(self.loop)
            self.outbound.endpoints.append(ep)
            self.endpoint_outputs.check_link_budget(ep)

    def _start_field_calibration(self) -> None:
        """The field magnetometer calibration (daemon.magcal), fed every sample."""
        host = DaemonMagCalHost(self.pipeline, self.swap, self.outbound, self.autopilot, self.positions,
                                self.heading.slew)
        self.field_calibration = FieldCalibrationPart(host, self.config.magcal or MagCalSettings(),
                                                      commands=self.commands, autopilot=self.autopilot,
                                                      set_calibrating=self.set_calibrating, clock=self.clock,
                                                      warm_fit_worker=self._warm_fit_worker)
        part = self.field_calibration
        self.listeners.add(part.on_sample, in_place=True, steps_ahead=part.steps_ahead,
                           runs=(part.on_run, part.takes_runs))

    def _open_nmea(self) -> None:
        """The [[nmea]] heading outputs, fed every estimate (none without any)."""
        if self.config.nmea:
            self.nmea = NmeaOutputs(self.config.nmea)
            self.nmea.open(self.loop)
            self.listeners.add(lambda _sample, est: self.nmea.on_estimate(est))

    def _register_builtin_commands(self) -> None:
        """The daemon's own MAVLink commands (daemon.builtin_commands)."""
        BuiltinCommands(endpoint_outputs=self.endpoint_outputs, publishers=self.publishers, outbound=self.outbound,
                        health=self.health, autopilot=self.autopilot,
                        field_calibration=self.field_calibration.protocol,
                        start_gyro_calibration=self._start_gyro_calibration,
                        call_soon=self.loop.call_soon, clock=self.clock).register(self.commands)

    def _open_gnss(self) -> None:
        """The GNSS task over the configured backend (none without a [gnss] source). It opens after the sensor
        source: a simulated receiver runs on the simulated chip's clock."""
        cfg = self.config
        if cfg.gnss.source == "none":
            return
        backend = gnss_backend_for(cfg.gnss, clock=self.clock, sensor=cfg.sensor,
                                   scenario_clock=self.source.chip.now if cfg.gnss.source == "sim" else None,
                                   replay_time_s=newest_sample_time(self.pipeline))
        self.gnss = GnssTask(backend, cfg.gnss, clock=self.clock, estimator=self.pipeline,
                             statustext=self.outbound.statustext, log_fix=self.logs.log_gnss_fix,
                             subscribers=[lambda fix: self.positions.note_live_position(),
                                          on_first_fix(self.declination.on_gnss_position)],
                             rejection_cause=self.heading_status.rejection_cause)
        # a receiver's fix is read after the outputs of the reader's next wake, not in front of them (#28)
        self.gnss.open(self.loop, after_output=self.reader.after_output if self.source is not None else None)

    def _start_status_line(self) -> None:
        """The live status line: `[daemon] status_line` on, or auto on a TTY."""
        mode = self.config.daemon.status_line
        want_line = mode == "on" or (mode == "auto" and self._stdout.isatty())
        self.status_line = StatusLine(self._stdout) if want_line else None
        if self.status_line is not None:
            self.status_line.install_log_filter()

    def _announce_start(self) -> None:
        """The start-up log line and systemd status, the health report, and the first heartbeat (routers learn
        us from our first packet)."""
        log.info("ahrsd started: %s, GNSS %s, estimator %s, declination %.2f° (%s), MAVLink %s as %d/%d, state in %s",
                 self.source.description, self.gnss.description if self.gnss else "none", self.config.estimator_name,
                 math.degrees(self.declination.rad), self.declination.source,
                 ", ".join(e.url for e in self.endpoints), self.system_id, self.component_id, self.state_dir)
        self.notifier.status(f"starting: {self.source.description}")
        self.health_report = HealthReport(self.health, self.outbound, self.notifier, self.pipeline.counters,
                                          watchdog_interval_s=watchdog_interval_s(self.environ),
                                          start=self.loop.time(), standby_detail=self.heading_status.standby_detail,
                                          active_detail=self.heading_status.active_detail,
                                          last_sample_t_s=lambda: self.pipeline.last_sample_t_s)
        self.health_report.send_heartbeat(self.clock())   # routers learn us from our first packet

    def _on_message(self, endpoint, msg) -> None:
        """Every endpoint's callback. The endpoints open before the inbound dispatch exists (it routes to the
        GNSS task, which needs the open sensor source), but no message is read before `start` returns."""
        self.inbound.on_message(endpoint, msg)

    def build_inbound(self) -> InboundDispatch:
        """The inbound dispatch over the parts that exist now (`start` builds it after the restart rule and
        the GNSS task; a test may build it after `start_restart_rule`)."""
        return InboundDispatch(self.outbound, self.autopilot, self.commands, self.param_protocol, self.declination,
                               follow_autopilot_id=self.config.mavlink.system_id == 0, gnss=self.gnss,
                               source_set_check=self.source_set_check, restart_heading=self.restart_heading,
                               clock=self.clock)

    def use_pipeline(self, pipeline: Pipeline) -> None:
        """Build the parts that work on the pipeline: the calibration swap, the publishers, the sample reader
        (its source is the service's; `start` calls this, a test may too with a pipeline of its own)."""
        self.pipeline = pipeline
        self.declination.set_estimator = pipeline.estimator.set_declination
        self.swap = CalibrationSwap(pipeline, self.state_dir, self.heading,
                                    reset_counter_on_calibration=self.config.outputs.reset_counter_on_calibration,
                                    on_applied=self._on_calibration_applied)
        self.publishers = Publishers(self.outbound, pipeline, self.health, self.counters, self)
        self.reader = SampleReader(self.source, pipeline, self.health, self.counters, self.listeners,
                                   ReaderOutputs(publish=self.publishers.publish, statustext=self.outbound.statustext,
                                                 heading_reset=self.heading.signal, ready=self._on_ready,
                                                 batch_done=self._on_replay_batch,
                                                 finished=lambda: self.request_stop(0),
                                                 next_due=self._next_output_due),
                                   poll_hz=self.config.sensor.poll_hz)

    def _next_output_due(self) -> float:
        """When a MAVLink or NMEA output falls due next (the event loop's clock; inf: none): the reader process
        hands its block over then (daemon.sample_reader)."""
        t = self.publishers.next_due()
        if self.nmea is not None:
            offset = self.source.monotonic_offset_s if self.source is not None else 0.0
            t = min(t, self.nmea.next_due_s() + offset)
        return t

    def _housekeeping(self) -> Housekeeping:
        """The periodic jobs, in the order they run at each tick (daemon.housekeeping)."""
        start = self.loop.time()
        jobs: list[Callable[[float], None]] = [self._update_heading_status, self.health_report]
        if self.status_line is not None:
            jobs.append(Every(STATUS_LINE_PERIOD_S, self._update_status_line, start))
        if self.signing_key is not None:
            jobs.append(Every(SIGNING_SAVE_PERIOD_S, lambda now: self._save_signing_timestamp(),
                              start + SIGNING_SAVE_PERIOD_S))
        if self.gnss is not None:
            jobs.append(self.gnss.tick)
        jobs += [self.declination.tick, self._end_unreceived_slew]
        return Housekeeping(jobs)

    def _update_heading_status(self, now: float) -> None:
        """The heading state (daemon.heading_status) into the health (MAV_STATE, SYS_STATUS bits) before the
        health report reads it; the learned iron's parameters and periodic save (daemon.learned_iron)."""
        if self.heading_status is not None:
            self.heading_status.on_estimate(self.pipeline.last_estimate, now, *self._yaw_resets(),
                                            field_circle=self._field_circle())
            self.health.heading_good = self.heading_status.heading_good
            self.health.heading_unhealthy_bits = self.heading_status.unhealthy_bits()
        if self.learned_iron is not None:
            self.learned_iron.tick(now)

    def _on_calibration_applied(self, cal) -> None:
        """After every calibration change (daemon.calibration_swap): the vehicle log names it; the estimator is
        told it; the heading status gets its predicted heading error; the iron learned on the old one is reset."""
        self.logs.log_calibration(cal)
        mag_sigma_rad = self._tell_calibration(self.pipeline.estimator, cal)
        if self.heading_status is not None:
            self.heading_status.set_calibration_sigma(mag_sigma_rad, in_force=has_mag_calibration(cal))
        if self.learned_iron is not None:
            self.learned_iron.calibration_changed()

    def _horizontal_field_ut(self) -> float:
        """WMM's horizontal field at the vehicle (daemon.position's priority), NaN without a position."""
        field = self.positions.reference_field()
        return math.nan if field is None else field.horizontal_ut

    def _update_status_line(self, now: float) -> None:
        p = self.pipeline
        self.status_line.update(format_status(
            estimate=p.last_estimate, rate_hz=self.health_report.measured_rate_hz,
            state=self.health.system_status(now), samples=sample_accounting(self),
            link=self.outbound.link_totals(), gnss=None if self.gnss is None else self.gnss.status(now),
            autopilot=self.autopilot,
            heading=None if self.heading_status is None
            else " ".join(filter(None, (self.heading_status.status_text(), self.heading.status_text())))))

    def _end_unreceived_slew(self, now: float) -> None:
        if self.heading.slew.active and not any(ep.schedule.rate_hz(VISION_POSITION_ESTIMATE) > 0
                                                for ep in self.endpoints):
            self.heading.slew.stop("no VPE sent")   # nobody receives the slewed yaw: nothing to bring in

    def _on_ready(self) -> None:
        self.notifier.ready("running")

    def _on_replay_batch(self, t_s: float) -> None:
        # a GNSS recording's fixes are due by the samples' time; a receiver with a descriptor is polled by the
        # event loop when it is readable, not at every batch (200 times a second, an ioctl and a read each)
        if self.gnss is not None and not self.gnss.polled_when_readable:
            self.gnss.poll()

    def _start_gyro_calibration(self, ctx) -> CommandAck:
        cal = GyroBiasCalibration(ctx, self.source.sample_rate_hz, listeners=self.listeners, loop=self.loop,
                                  health=self.health, outbound=self.outbound, autopilot=self.autopilot,
                                  swap=self.swap)
        return cal.start()

    def start_restart_rule(self) -> None:
        """Load what the autopilot last got from us (daemon.restart_heading): the reset_counter continues,
        and a different heading after the restart is brought in as `[outputs] restart_yaw` says (slewed, or
        a yaw reset: reset_counter for PX4, an EKF source-set switch for ArduPilot)."""
        out = self.config.outputs
        mode = "reset_counter" if out.restart_yaw == "auto" and out.reset_counter_on_calibration else out.restart_yaw
        make_realign = None
        if out.ardupilot_source_set:
            check = self.source_set_check = SourceSetCheck(out.ardupilot_source_set, self.outbound.send,
                                                           self._autopilot_target)

            def make_realign() -> SourceSetRealign | None:
                if not check.allowed:
                    log.warning("restart: not switching ArduPilot's EKF source set (%s)",
                                check.verdict[1] if check.verdict else "its EK3_SRC parameters not read yet")
                    return None
                return SourceSetRealign(out.ardupilot_source_set, send_command=self._send_source_set_command,
                                        warn_operator=lambda text: self.statustext(mavlink.MAV_SEVERITY_CRITICAL, text))
        self.restart_heading = RestartHeading(
            self.state_dir, self.heading.slew, mode=mode, signal_reset=self.heading.signal,
            slew_rate_deg_s=out.restart_slew_deg_s, autopilot_kind=lambda: self.autopilot.autopilot_kind,
            make_realign=make_realign, background=self._in_background)
        self.heading.reset_counter = self.restart_heading.initial_reset_counter
        self.heading.restart = self.restart_heading

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

    def _save_signing_timestamp(self) -> None:
        save_timestamp(self.state_dir, max(e.signing_timestamp() for e in self.endpoints))

    def shutdown_io(self, why: str) -> None:
        if self.status_line:
            self.status_line.clear()
        self.notifier.stopping(why)
        if self.endpoints:
            self.statustext(mavlink.MAV_SEVERITY_NOTICE, "ahrsd: stopping")
            self.send(msgs.heartbeat(self.outbound.identity.mav_type, mavlink.MAV_STATE_POWEROFF))
        if self.signing_key is not None:
            save_timestamp(self.state_dir, max((e.signing_timestamp() for e in self.endpoints), default=0))
        if self.restart_heading is not None:
            self.restart_heading.save_now(self.heading.reset_counter)
        if self.learned_iron is not None:
            self.learned_iron.save_now()
        self.positions.memory.save_now()
        if self.reader is not None:
            self.reader.outputs.raw_sink = None
        self.logs.close(self.endpoints)             # after the last frames went out
        for ep in self.endpoints:
            ep.close()
        if self.nmea is not None:
            self.nmea.close()
        if self.field_calibration is not None:
            self.field_calibration.close()
        if self.gnss is not None:
            self.gnss.close()
        if self.source is not None:
            self.source.close()
        self.notifier.close()
