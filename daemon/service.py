"""The daemon: one asyncio event loop running the sensor reader, the estimator, the publishers, the MAVLink
receivers and the housekeeping (heartbeat, health, watchdog, status line).

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

from ahrsd.daemon import messages as msgs
from ahrsd.daemon.autopilot import AutopilotState
from ahrsd.daemon.commands import CommandRouter
from ahrsd.daemon.config import MAV_TYPES, Config
from ahrsd.daemon.health import STATE_NAMES, Health
from ahrsd.daemon.mavlink_io import Endpoint, is_for_us, mavlink
from ahrsd.daemon.notify import Notifier, watchdog_interval_s
from ahrsd.daemon.outputs import OUTPUT_KEYS, OutputSchedule
from ahrsd.daemon.params import ParamError, ParamSpec, ParamStore, decode_param_id
from ahrsd.daemon.rate_limit import TokenBucket
from ahrsd.daemon.pipeline import Pipeline, open_source
from ahrsd.core.angles import yaw_rate_ned_rad_s
from ahrsd.daemon.heading_slew import HeadingSlew
from ahrsd.drivers.errors import FrameError
from ahrsd.core.sample import SampleFlags
from ahrsd.daemon.status_line import StatusLine, format_status
from ahrsd.core.estimate import EstimateFlags

log = logging.getLogger(__name__)

HOUSEKEEPING_HZ = 10.0
STATUS_LINE_PERIOD_S = 0.5
SIGNING_SAVE_PERIOD_S = 30.0
DECLINATION_UPDATE_PERIOD_S = 10.0
DECLINATION_RESET_STEP_RAD = math.radians(0.5)   # a heading step this large increments reset_counter
PARAM_STREAM_PAUSE_S = 0.002                     # pause between PARAM_VALUEs of a list (anchor §1.6)
DRIVER_RETRY_S = 0.2
FRAME_ERRORS_FOR_FAILURE = 100                   # consecutive corrupt frames (≈ 0.12 s) = sensor failure
DEFAULT_SYSTEM_ID = 1                            # until an autopilot heartbeat is latched

# IntFlag operators go through the enum machinery (µs each); the per-sample path tests bits on plain ints
_int_and = int.__and__
_GAP_BEFORE = int(SampleFlags.GAP_BEFORE)
_REINITIALISED = int(EstimateFlags.REINITIALISED)
_INITIALISING = int(EstimateFlags.INITIALISING)

PARAM_RATE_NAMES = {
    "attitude_hz": "SR_ATTITUDE", "attitude_quaternion_hz": "SR_ATT_QUAT",
    "vision_position_estimate_hz": "SR_VISION_POS", "highres_imu_hz": "SR_HIGHRES_IMU",
    "scaled_imu_hz": "SR_SCALED_IMU", "sys_status_hz": "SR_SYS_STATUS",
}


@dataclass
class ServiceCounters:
    wakes: int = 0
    overruns: int = 0            # reader wakes that started after their deadline by more than one period
    driver_errors: int = 0       # bus failures (and runs of corrupt frames) that put the sensor in failure
    frame_errors: int = 0        # single corrupt frames rejected by the driver
    unsigned_refused: int = 0    # PARAM_SET refused unsigned (commands are counted by the router)
    published: int = 0
    statustext_suppressed: int = 0  # non-critical STATUSTEXTs dropped by the rate limit (flooding peer)


def param_specs(cfg: Config) -> list[ParamSpec]:
    """The stable parameter set (names, order and ranges never change while running)."""
    out = []
    for key, name in PARAM_RATE_NAMES.items():
        hi = 50.0 if key == "vision_position_estimate_hz" else 200.0
        out.append(ParamSpec(name, getattr(cfg.outputs, key), 0.0, hi, f"{key[:-3]} rate, Hz (0 = off)"))
    r, p, y = cfg.sensor.mounting_rpy_deg
    out += [
        ParamSpec("MNT_ROLL_DEG", r, -180.0, 180.0, "sensor mounting roll in the body frame, deg"),
        ParamSpec("MNT_PITCH_DEG", p, -90.0, 90.0, "sensor mounting pitch in the body frame, deg"),
        ParamSpec("MNT_YAW_DEG", y, -180.0, 180.0, "sensor mounting yaw in the body frame, deg"),
        ParamSpec("DECL_MANUAL", 1.0 if cfg.location.declination_deg is not None else 0.0, 0.0, 1.0,
                  "1 = use DECL_DEG, 0 = WMM at the configured or autopilot position", integer=True),
        ParamSpec("DECL_DEG", cfg.location.declination_deg or 0.0, -180.0, 180.0,
                  "magnetic declination, deg east (used when DECL_MANUAL = 1)"),
    ]
    return out


class Service:
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
        self.schedule = OutputSchedule({mid: getattr(config.outputs, key) for key, mid in OUTPUT_KEYS.items()})
        self.params = ParamStore(param_specs(config), self.state_dir, on_change=self._on_param_change)
        self.commands = CommandRouter(self, self._send_on, require_signed=lambda: self.signing_required,
                                      accept_broadcast=config.mavlink.accept_broadcast_commands)
        self.notifier = Notifier(environ)
        self.source = source
        self.pipeline: Pipeline | None = None
        self.reset_counter = 0
        # the VISION_POSITION_ESTIMATE yaw after a calibration change (apply_calibration)
        self.heading_slew = HeadingSlew(max_rate_deg_s=config.outputs.heading_slew_deg_s)
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
    def calibration(self):
        return self.pipeline.calibration

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

    def apply_calibration(self, cal, *, save: bool = True, reason: str = "") -> None:
        """Persist (when `save`; an error propagates and the previous calibration stays in force and on disk)
        and swap the calibration atomically between two samples. The one path for every calibration change
        (mag-cal accept/autosave, fixed yaw, gyro calibration).

        The estimator re-learns its field reference (`relearn_field_reference`: it would otherwise reject
        the corrected field as a disturbance and jump later), and the yaw in VISION_POSITION_ESTIMATE moves to
        the new heading at no more than `[outputs] heading_slew_deg_s` (EKF3 rejects a yaw step beyond its
        3σ gate in flight). reset_counter is left alone unless `reset_counter_on_calibration`: ArduPilot
        reads a new value as a position reset, PX4 EKF2 as a yaw reset (docs/daemon.md "reset_counter").
        """
        if save:
            from ahrsd.calibration.store import CalibrationStore

            CalibrationStore(self.state_dir).save(cal)
        self.pipeline.calibration = cal
        relearn = getattr(self.pipeline.estimator, "relearn_field_reference", None)
        if relearn is not None:
            relearn()
        if self.config.outputs.reset_counter_on_calibration:
            self.signal_heading_reset()
        else:
            self.heading_slew.start_transition()
        log.info("calibration applied%s", f" ({reason})" if reason else "")

    def signal_heading_reset(self) -> None:
        """A heading discontinuity the autopilot is told about (estimator re-initialised, mounting or
        declination changed): VISION_POSITION_ESTIMATE.reset_counter + 1, and the yaw is sent as it is (any
        calibration slew still running ends: the reset replaces it)."""
        self.reset_counter += 1
        self.heading_slew.active = False

    def request_stop(self, code: int = 0) -> None:
        self.exit_code = code
        if self._stop is not None:
            self._stop.set()

    def link_totals(self) -> dict:
        tx = sum(ep.counters.tx_messages for ep in self.endpoints)
        rx = sum(ep.counters.rx_messages for ep in self.endpoints)
        bad = sum(ep.counters.rx_malformed + ep.counters.rx_bad_signature for ep in self.endpoints)
        return {"tx": tx, "rx": rx, "bad": bad}

    def time_boot_ms(self, now: float | None = None) -> int:
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
        from ahrsd.calibration.store import CalibrationStore
        from ahrsd.estimator import make_estimator

        cfg = self.config
        try:
            self.state_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            log.warning("state directory %s unusable (%s): calibration and parameters will not persist",
                        self.state_dir, exc)
        for warning in self.params.load():
            log.warning("%s", warning)
        self._resolve_declination(initial=True)
        calibration = CalibrationStore(self.state_dir).load()
        estimator = make_estimator(cfg.estimator.name, declination_rad=self.declination_rad)
        self.pipeline = Pipeline(estimator, calibration)
        self.pipeline.set_mounting([self.params.get(n) for n in ("MNT_ROLL_DEG", "MNT_PITCH_DEG", "MNT_YAW_DEG")])
        for key, name in PARAM_RATE_NAMES.items():
            self.schedule.set_rate_hz(OUTPUT_KEYS[key], self.params.get(name), default=True)
        self._setup_signing()
        for ep_cfg in cfg.endpoints:
            ep = Endpoint(ep_cfg.url, self.system_id, self.component_id, self._on_message)
            if self.signing_key is not None:
                from ahrsd.daemon.signing import initial_timestamp

                ep.enable_signing(self.signing_key, cfg.signing.link_id, initial_timestamp(self.state_dir),
                                  lambda _mav, _msgid: True)   # unsigned input is accepted, then policed
            ep.open(self.loop)
            self.endpoints.append(ep)
        from ahrsd.daemon.builtin_commands import register_builtin_commands

        register_builtin_commands(self)
        self._attach_magcal()
        if self.source is None:
            self.source = open_source(cfg.sensor, clock=time.monotonic)
        want_line = cfg.daemon.status_line == "on" or (cfg.daemon.status_line == "auto" and self._stdout.isatty())
        self._status_line = StatusLine(self._stdout) if want_line else None
        if self._status_line is not None:
            self._status_line.install_log_filter()
        log.info("ahrsd started: %s, estimator %s, declination %.2f° (%s), MAVLink %s as %d/%d, state in %s",
                 self.source.description, cfg.estimator.name, math.degrees(self.declination_rad),
                 self.declination_source, ", ".join(e.url for e in self.endpoints), self.system_id,
                 self.component_id, self.state_dir)
        self.notifier.status(f"starting: {self.source.description}")
        self._send_heartbeat(time.monotonic())   # routers learn us from our first packet (anchor §3.1)

    def _attach_magcal(self) -> None:
        """The field magnetometer calibration (issue 7) plugs in through the public hooks."""
        try:
            from ahrsd.daemon.magcal import attach
        except ImportError:
            log.info("magnetometer calibration module not available")
            return
        try:
            attach(self)
        except Exception:  # noqa: BLE001 - the daemon runs without it rather than not at all
            log.exception("magnetometer calibration could not be attached; running without it")

    def _setup_signing(self) -> None:
        if not self.config.signing.key_file:
            return
        from ahrsd.daemon.signing import key_fingerprint, load_key

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
            from ahrsd.daemon.signing import save_timestamp

            save_timestamp(self.state_dir, max((e.signing_timestamp() for e in self.endpoints), default=0))
        for ep in self.endpoints:
            ep.close()
        if self.source is not None:
            self.source.close()
        self.notifier.close()

    # ------------------------------------------------------------------------------------------ sensor reader

    async def _reader(self) -> None:
        if getattr(self.source, "per_sample", False):
            await self._read_per_sample()
        else:
            await self._read_batched()

    async def _read_per_sample(self) -> None:
        """Read the chip once per sample, right after it becomes ready (pipeline.SampleTimer).

        Deadlines are absolute CLOCK_MONOTONIC times served by a timerfd on the event loop
        (daemon.timerfd; asyncio alone sleeps in whole milliseconds); each expiry runs `_reader_step`.
        A wake later than a whole period loses a sample on the chip: it is counted (GAP_BEFORE, pipeline
        gaps, overruns) and the estimator sees the true time step.
        """
        from ahrsd.daemon.timerfd import DeadlineTimer

        loop = self.loop
        self._reader_period = 1.0 / self.source.sample_rate_hz
        self._reader_done = loop.create_future()
        self._reader_timer = DeadlineTimer(loop, self._reader_step)
        self._reader_timer.arm(loop.time())
        try:
            await self._reader_done
        finally:
            self._reader_timer.close()

    def _reader_step(self) -> None:
        """One wake of the per-sample reader: read, process, publish, arm the next deadline."""
        loop, source, timer = self.loop, self.source, self._reader_timer
        now = loop.time()
        self.counters.wakes += 1
        try:
            try:
                sample = source.read_one(now)
            except FrameError as exc:
                # one corrupt frame: the driver counted it; the next sample comes one period later
                self.counters.frame_errors += 1
                self._consecutive_frame_errors += 1
                if self._consecutive_frame_errors >= FRAME_ERRORS_FOR_FAILURE:
                    self._on_driver_error(exc)
                self._publish(now)      # SYS_STATUS keeps flowing (health bits) while the sensor misbehaves
                timer.arm(now + self._reader_period)
                return
            except Exception as exc:  # noqa: BLE001 - BusError or an OSError: count, report, retry
                self._on_driver_error(exc)
                self._publish(now)      # only SYS_STATUS goes out now: the GCS sees the health bits cleared
                timer.arm(now + DRIVER_RETRY_S)
                return
            self._consecutive_frame_errors = 0
            if sample is not None:
                if _int_and(sample.flags, _GAP_BEFORE):
                    self.counters.overruns += 1
                self._process((sample,), now)
            after = loop.time()
            self._publish(after)
            target = source.next_read_time()
            if target <= after:
                target = after + (0.25 * self._reader_period if sample is None else 0.0)
            timer.arm(target)
        except Exception as exc:  # noqa: BLE001 - a bug here ends the reader; run() exits non-zero
            if not self._reader_done.done():
                self._reader_done.set_exception(exc)

    async def _read_batched(self) -> None:
        """Replay: poll on a fixed absolute-deadline tick and process every sample that is due."""
        loop, source = self.loop, self.source
        period = 1.0 / self.config.sensor.poll_hz
        deadline = loop.time()
        while True:
            deadline += period
            now = loop.time()
            self.counters.wakes += 1
            try:
                samples = source.poll()
            except Exception as exc:  # noqa: BLE001
                self._on_driver_error(exc)
                await asyncio.sleep(DRIVER_RETRY_S)
                deadline = loop.time()
                continue
            if samples:
                self._process(samples, now)
            elif getattr(source, "finished", False):
                log.info("replay finished")
                self.request_stop(0)
                return
            self._publish(now)
            after = loop.time()
            if after - deadline > period:
                self.counters.overruns += 1
                deadline = after
            await asyncio.sleep(max(0.0, deadline - after))

    def _process(self, samples, now: float) -> None:
        """The per-sample hot path: pipeline, listeners, health bookkeeping."""
        health, pipeline = self.health, self.pipeline
        if health.sensor_error:
            health.sensor_error = ""
            self.statustext(mavlink.MAV_SEVERITY_NOTICE, "ahrsd: sensor recovered")
        est = None
        listeners = self._listeners
        for raw in samples:
            est = pipeline.process(raw)
            if listeners and est is not None:
                for fn in tuple(listeners):
                    try:
                        fn(pipeline.last_sample, est)
                    except Exception:  # noqa: BLE001 - a faulty listener is dropped, the reader carries on
                        log.exception("sample listener %r failed; removed", fn)
                        listeners.remove(fn)
        health.last_sample_time = now
        health.last_sample_flags = samples[-1].flags
        if est is not None:
            if _int_and(est.flags, _REINITIALISED):
                self.signal_heading_reset()       # a genuine re-initialisation: signalled, not slewed
            health.last_estimate_flags = est.flags
            if not self.ready_sent and not _int_and(est.flags, _INITIALISING):
                self.ready_sent = True
                self.notifier.ready("running")
                log.info("first good estimate: READY")

    def sample_time_monotonic(self, t_s: float) -> float:
        """CLOCK_MONOTONIC time of a sample stamped t_s (the chip source stamps in that clock already;
        a replay is shifted to the moment it started)."""
        return t_s + getattr(self.source, "monotonic_offset_s", 0.0)

    def _on_driver_error(self, exc: Exception) -> None:
        self.counters.driver_errors += 1
        first = not self.health.sensor_error
        self.health.sensor_error = str(exc) or type(exc).__name__
        if first:
            log.error("sensor read failed: %s", exc)
            self.statustext(mavlink.MAV_SEVERITY_CRITICAL, f"ahrsd: sensor failure: {self.health.sensor_error}")

    # ------------------------------------------------------------------------------------------ publishers

    def _publish(self, now: float) -> None:
        due = self.schedule.due(now)
        if not due:
            return
        est = self.pipeline.last_estimate
        sample = self.pipeline.last_sample
        fresh = self.health.samples_flowing(now) and not self.health.sensor_error
        for mid in due:
            m = None
            if mid == msgs.mavlink.MAVLINK_MSG_ID_SYS_STATUS:
                m = self._sys_status(now)
            elif fresh and est is not None:
                m = self._build(mid, est, sample, now)
            if m is not None:
                self.send(m)
                self.counters.published += 1

    def build_output(self, mid: int, now: float):
        """The output message `mid` from the current state (REQUEST_MESSAGE), or None if it cannot be sent."""
        if mid == mavlink.MAVLINK_MSG_ID_SYS_STATUS:
            return self._sys_status(now)
        est = self.pipeline.last_estimate
        return None if est is None else self._build(mid, est, self.pipeline.last_sample, now)

    def _build(self, mid: int, est, sample, now: float):
        """One output message from the latest estimate/sample, or None when it must not be sent now."""
        if mid == mavlink.MAVLINK_MSG_ID_ATTITUDE:
            return msgs.attitude(est, self.time_boot_ms(now), est.heading_true_rad)
        if mid == mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION:
            return msgs.attitude_quaternion(est, self.time_boot_ms(now), self.declination_rad)
        if mid == mavlink.MAVLINK_MSG_ID_VISION_POSITION_ESTIMATE:
            if not self.health.heading_trusted(now):
                return None   # never feed the autopilot a heading it must not trust (design §6)
            usec = int(self.sample_time_monotonic(est.t_s) * 1e6)
            yaw = self.heading_slew.update(est.t_s, est.heading_true_rad,
                                           yaw_rate_ned_rad_s(est.rate_body_rad_s, est.roll_rad, est.pitch_rad))
            return msgs.vision_position_estimate(est, usec, yaw, self.reset_counter)
        if mid == mavlink.MAVLINK_MSG_ID_HIGHRES_IMU and sample is not None:
            return msgs.highres_imu(sample, int(self.sample_time_monotonic(sample.t_s) * 1e6))
        if mid == mavlink.MAVLINK_MSG_ID_SCALED_IMU and sample is not None:
            return msgs.scaled_imu(sample, self.time_boot_ms(now))
        return None

    def _sys_status(self, now: float):
        present, enabled, healthy = self.health.sensor_bits(now)
        links = self.endpoints
        errors_comm = sum(e.counters.rx_malformed + e.counters.rx_bad_signature for e in links)
        pc = self.pipeline.counters
        unsigned = self.commands.counters.unsigned_refused + self.counters.unsigned_refused
        sensor_errors = self.counters.driver_errors + self.counters.frame_errors
        return msgs.sys_status(present, enabled, healthy, self.load_permille, errors_comm,
                               (unsigned, pc.lost_samples, self.counters.overruns, sensor_errors))

    def _send_heartbeat(self, now: float) -> None:
        self.send(msgs.heartbeat(self.mav_type, self.health.system_status(now)))

    # ------------------------------------------------------------------------------------------ housekeeping

    async def _housekeeping(self) -> None:
        loop = self.loop
        period = 1.0 / HOUSEKEEPING_HZ
        wd_interval = watchdog_interval_s(self.environ)
        start = loop.time()
        next_hb = start + 1.0
        next_wd = start
        next_line = start
        next_sign = start + SIGNING_SAVE_PERIOD_S
        deadline = start
        while True:
            deadline += period
            now = loop.time()
            if now >= next_hb:
                next_hb = max(next_hb + 1.0, now)
                self._update_load(now)
                self._send_heartbeat(now)
            state = self.health.system_status(now)
            if state != self._last_state:
                self._on_state_change(self._last_state, state)
                self._last_state = state
            if wd_interval is not None and now >= next_wd and self.health.samples_flowing(now):
                self.notifier.watchdog()     # only while samples flow: a stalled reader gets us restarted
                next_wd = now + wd_interval
            if self._status_line is not None and now >= next_line:
                next_line = now + STATUS_LINE_PERIOD_S
                self._status_line.update(format_status(self, now))
            if self.signing_key is not None and now >= next_sign:
                from ahrsd.daemon.signing import save_timestamp

                next_sign = now + SIGNING_SAVE_PERIOD_S
                save_timestamp(self.state_dir, max(e.signing_timestamp() for e in self.endpoints))
            if now - self._last_decl_update > DECLINATION_UPDATE_PERIOD_S:
                self._resolve_declination()
            if self.heading_slew.active and self.schedule.rate_hz(OUTPUT_KEYS["vision_position_estimate_hz"]) <= 0:
                self.heading_slew.active = False    # nobody receives the slewed yaw: nothing to bring in
            await asyncio.sleep(max(0.0, deadline - loop.time()))

    def _update_load(self, now: float) -> None:
        t0, cpu0 = self._cpu_window
        cpu = time.process_time()
        if now > t0:
            self.load_permille = int(1000.0 * (cpu - cpu0) / (now - t0))
        self._cpu_window = (now, cpu)
        t_prev, n_prev = self._rate_window
        n = self.pipeline.counters.samples
        if t_prev:
            self.measured_rate_hz = (n - n_prev) / (now - t_prev)
        self._rate_window = (now, n)

    def _on_state_change(self, old: int | None, new: int) -> None:
        name = STATE_NAMES.get(new, str(new))
        severity = {mavlink.MAV_STATE_CRITICAL: mavlink.MAV_SEVERITY_CRITICAL,
                    mavlink.MAV_STATE_ACTIVE: mavlink.MAV_SEVERITY_NOTICE}.get(new, mavlink.MAV_SEVERITY_INFO)
        detail = {
            mavlink.MAV_STATE_BOOT: "waiting for the sensor",
            mavlink.MAV_STATE_STANDBY: "initialising, no heading out",
            mavlink.MAV_STATE_ACTIVE: "heading good",
            mavlink.MAV_STATE_CALIBRATING: self.health.calibrating or "calibrating",
            mavlink.MAV_STATE_CRITICAL: self.health.sensor_error or "no samples from the sensor",
        }.get(new, "")
        self.statustext(severity, f"ahrsd: {name}: {detail}"[:50])
        self.notifier.status(f"{name}: {detail}")

    # ------------------------------------------------------------------------------------------ declination

    def _resolve_declination(self, initial: bool = False) -> None:
        """Declination by priority: DECL_MANUAL/DECL_DEG, configured position, autopilot position, sim site."""
        from ahrsd.core.wmm import earth_field

        self._last_decl_update = time.monotonic()
        loc = self.config.location
        decl, source = None, ""
        if self.params.get("DECL_MANUAL") >= 0.5:
            decl, source = math.radians(self.params.get("DECL_DEG")), "manual"
        elif loc.lat_deg is not None:
            decl = earth_field(loc.lat_deg, loc.lon_deg, loc.alt_m).declination_rad
            source = f"WMM at {loc.lat_deg:.4f},{loc.lon_deg:.4f} (config)"
        elif loc.use_autopilot_position and self.autopilot.lat_deg is not None:
            ap = self.autopilot
            decl = earth_field(ap.lat_deg, ap.lon_deg, ap.alt_m).declination_rad
            source = f"WMM at {ap.lat_deg:.4f},{ap.lon_deg:.4f} (autopilot)"
        elif self.config.sensor.source == "sim":
            from ahrsd.simulation import DEFAULT_SITE

            site = DEFAULT_SITE
            decl = earth_field(site.lat_deg, site.lon_deg, site.alt_m, site.date).declination_rad
            source = "WMM at the simulator's site"
        if decl is None:
            if initial:
                log.warning("no position and no declination configured: true heading = magnetic heading until "
                            "the autopilot reports a position")
            decl, source = 0.0, "none (no position yet)"
        self._set_declination(decl, source)

    def _set_declination(self, decl: float, source: str) -> None:
        step = abs(math.remainder(decl - self.declination_rad, 2 * math.pi))
        if source != self.declination_source:
            log.info("declination %.2f° from %s", math.degrees(decl), source)
        self.declination_rad, self.declination_source = decl, source
        if self.pipeline is not None and step > 1e-9:
            self.pipeline.estimator.set_declination(decl)
            if step > DECLINATION_RESET_STEP_RAD:
                self.signal_heading_reset()

    # ------------------------------------------------------------------------------------------ parameters

    def _on_param_change(self, name: str, value: float) -> None:
        if name.startswith("SR_"):
            key = next(k for k, n in PARAM_RATE_NAMES.items() if n == name)
            try:
                self.schedule.set_rate_hz(OUTPUT_KEYS[key], value, default=True)
            except ValueError as exc:
                raise ParamError(f"{name}: {exc}") from None
        elif name.startswith("MNT_"):
            if self.pipeline is not None:
                rpy = [self.params.get(n) for n in ("MNT_ROLL_DEG", "MNT_PITCH_DEG", "MNT_YAW_DEG")]
                rpy[("MNT_ROLL_DEG", "MNT_PITCH_DEG", "MNT_YAW_DEG").index(name)] = value
                self.pipeline.set_mounting(rpy)
                self.signal_heading_reset()
        elif name in ("DECL_MANUAL", "DECL_DEG"):
            self.loop.call_soon(self._resolve_declination)

    def _param_value(self, index: int):
        name, value = self.params.item(index)
        return msgs.param_value(name, value, index, len(self.params))

    async def _stream_params(self, endpoint: Endpoint) -> None:
        for i in range(len(self.params)):
            endpoint.send(self._param_value(i))
            await asyncio.sleep(PARAM_STREAM_PAUSE_S)

    def _on_param_message(self, endpoint: Endpoint, msg, mtype: str, broadcast: bool) -> None:
        if mtype == "PARAM_REQUEST_LIST":
            self.loop.create_task(self._stream_params(endpoint))
            return
        name = decode_param_id(msg.param_id)
        if mtype == "PARAM_REQUEST_READ":
            index = msg.param_index if msg.param_index >= 0 else self.params.index_of(name)
            if index is None or index >= len(self.params):
                if not broadcast:
                    self.statustext(mavlink.MAV_SEVERITY_WARNING, f"ahrsd: unknown parameter {name}"[:50])
                return
            endpoint.send(self._param_value(index))
            return
        # PARAM_SET
        index = self.params.index_of(name)
        if index is None:
            if not broadcast:
                self.params.rejected_writes += 1
                self.statustext(mavlink.MAV_SEVERITY_WARNING, f"ahrsd: unknown parameter {name}"[:50])
            return
        if self.signing_required and not msg.get_signed():
            self.counters.unsigned_refused += 1
            self.statustext(mavlink.MAV_SEVERITY_WARNING, f"ahrsd: unsigned write of {name} refused"[:50])
        else:
            ok, reason = self.params.set(name, msg.param_value)
            if not ok:
                self.statustext(mavlink.MAV_SEVERITY_WARNING, f"ahrsd: {reason}"[:50])
                log.warning("PARAM_SET refused: %s", reason)
        self.send(self._param_value(index))   # always answered, with the value in force (anchor §1.6)

    # ------------------------------------------------------------------------------------------ MAVLink input

    def _send_on(self, endpoint: Endpoint, msg) -> None:
        endpoint.send(msg)

    def _on_message(self, endpoint: Endpoint, msg) -> None:
        src_sys, src_comp = msg.get_srcSystem(), msg.get_srcComponent()
        if src_sys == self.system_id and src_comp == self.component_id:
            return   # our own traffic echoed back by a router or a broadcast link
        mtype = msg.get_type()
        now = time.monotonic()
        if mtype == "HEARTBEAT":
            if AutopilotState.is_autopilot_heartbeat(msg) and self.autopilot.on_heartbeat(msg, now):
                log.info("autopilot found: system %d component %d", src_sys, src_comp)
                if self.config.mavlink.system_id == 0 and src_sys != self.system_id:
                    self.system_id = src_sys
                    for ep in self.endpoints:
                        ep.set_system_id(src_sys)
            return
        if mtype in ("GLOBAL_POSITION_INT", "GPS_RAW_INT"):
            if self.autopilot.system_id is None or src_sys == self.autopilot.system_id:
                if mtype == "GLOBAL_POSITION_INT":
                    self.autopilot.on_global_position_int(msg, now)
                else:
                    self.autopilot.on_gps_raw_int(msg, now)
                if self.declination_source.startswith("none"):
                    self._resolve_declination()
            return
        if mtype == "TIMESYNC":
            if msg.tc1 == 0:   # a request; answers have tc1 != 0 (anchor §1.6 timesync v2)
                endpoint.send(msgs.timesync_reply(time.monotonic_ns(), msg.ts1))
            return
        if mtype in ("COMMAND_LONG", "COMMAND_INT"):
            ours, broadcast = is_for_us(msg, self.system_id, self.component_id)
            if ours:
                self.commands.handle(msg, endpoint, broadcast)
            return
        if mtype in ("PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET"):
            ours, broadcast = is_for_us(msg, self.system_id, self.component_id)
            if ours:
                self._on_param_message(endpoint, msg, mtype, broadcast)
