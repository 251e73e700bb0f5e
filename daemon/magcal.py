"""The MAVLink side of the field magnetometer recalibration (ArduPilot's onboard-calibration protocol).

Commands (COMMAND_LONG / COMMAND_INT), behaviour mirrored from ArduPilot's AP_Compass_Calibration.cpp
(ArduPilot/ardupilot) so Mission Planner, MAVProxy and any MAVLink client can drive our component:

* MAV_CMD_DO_START_MAG_CAL (42424): p1 magnetometer mask (0 = all; ours is compass 0), p2 retry, p3 autosave,
  p4 delay s, p5 autoreboot (not needed: the new calibration is hot-swapped; logged and ignored).
  ACCEPTED as ArduPilot does; FAILED for a mask outside 0..255 or one that names no compass of ours, for
  retry/autosave/autoreboot other than 0/1 and for a delay that is not finite or outside 0..timeout_s;
  TEMPORARILY_REJECTED + STATUSTEXT "Disarm to allow compass calibration" while the autopilot reports armed
  (ArduPilot answers FAILED; TEMPORARILY_REJECTED tells the client to retry later, common.xml
  MAV_RESULT) unless `allow_armed`; a second start
  while a session runs is ACCEPTED and changes nothing (ArduPilot's CompassCalibrator::start returns when
  running); a start after a finished session starts a new one.
* MAV_CMD_DO_ACCEPT_MAG_CAL (42425): saves a SUCCESS result (atomic store, previous kept), hot-swaps it,
  logs before/after and stops the session, then answers; ACCEPTED only when the result is saved (also for an
  accept repeated after it was saved: a re-sent command whose first ACK was lost), FAILED for a FAILED session
  (stopped), for a session still running (which carries on: ArduPilot would stop it, which only throws the
  operator's turning away) and when there is nothing to accept (no session, or it was cancelled), with a
  STATUSTEXT saying so. ArduPilot answers ACCEPTED there; a client would then report a calibration saved that
  was not (#30: `ahrsd magcal accept` after the session had been cancelled said ACCEPTED).
* MAV_CMD_DO_CANCEL_MAG_CAL (42426): stops the session, ACCEPTED; "Mag cal cancelled" when a session running
  or waiting for its accept is dropped (a terminal still following it learns it was settled elsewhere).
* MAV_CMD_FIXED_MAG_CAL_YAW (42006): p1 true yaw deg, p2 mask, p3/p4 lat/lon (0/0 = the daemon's
  position, daemon.position's priority; as COMMAND_INT the position may come as x/y in degE7):
  offsets from the WMM field at the given attitude, soft iron KEPT; saved and swapped at once (as ArduPilot
  does). DENIED up front for a yaw or position that is not finite or out of range. Computed from the raw
  (uncalibrated) field, so the same request twice gives the same calibration.
* MAV_CMD_PREFLIGHT_CALIBRATION (241) p2 = 1 starts (retry 0, autosave 1), p2 = 76 accepts — only when the
  daemon has not claimed 241 itself (it can delegate with `handle_preflight_mag`).

Broadcasts (target_component 0) are ignored unless `accept_broadcast` (MAVProxy's `magcal` sends them, and
they would start the autopilot's own calibration too); unsigned commands are refused when signing is
configured (both done by the CommandRouter, daemon/commands.py).

While a session runs: MAG_CAL_PROGRESS at ~4 Hz, HEARTBEAT system_status CALIBRATING (`system_status`),
STATUSTEXT lines a person can act on; when it has finished, MAG_CAL_REPORT (ArduPilot's offsets/diag/offdiag
convention, fitness in mgauss, autosaved flag) at 1 Hz until accepted or cancelled. Save and swap go
through the daemon's one calibration path, daemon.calibration_swap, which also has the estimator
re-learn its field reference and slews the heading sent to the autopilot (docs/daemon.md "Calibration
changes").
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import concurrent.futures.process
import itertools
import logging
import math
import time
from collections import deque
from typing import Any, Protocol

import numpy as np

from ahrsd.calibration.ardupilot_compass import UT_TO_MGAUSS
from ahrsd.calibration.field import CalStatus, FieldAttitude, FieldCalConfig, FieldCalibration, VehicleType
from ahrsd.calibration.fixed_yaw import fixed_yaw_calibration
from ahrsd.core.angles import tilt_compensated_heading_rad, wrap_180_deg
from ahrsd.core.wmm import earth_field
from ahrsd.daemon.autopilot import AutopilotState
from ahrsd.daemon.calibration_swap import CalibrationSwap
from ahrsd.daemon.command_args import CommandArgs, Refused, position_problem, whole_number
from ahrsd.daemon.heading_slew import HeadingSlew
from ahrsd.daemon.magcal_settings import MagCalSettings, settings_from_mapping  # noqa: F401 - re-exported
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.outbound import Outbound
from ahrsd.daemon.position import PositionResolver
from ahrsd.drivers.gnss.mavlink import MavlinkGnssSelector
from ahrsd.estimator.rotations import euler_to_dcm

log = logging.getLogger(__name__)

CMD_START = 42424       # MAV_CMD_DO_START_MAG_CAL (ardupilotmega.xml)
CMD_ACCEPT = 42425      # MAV_CMD_DO_ACCEPT_MAG_CAL
CMD_CANCEL = 42426      # MAV_CMD_DO_CANCEL_MAG_CAL
CMD_FIXED_YAW = 42006   # MAV_CMD_FIXED_MAG_CAL_YAW (common.xml)
CMD_PREFLIGHT = 241     # MAV_CMD_PREFLIGHT_CALIBRATION
PREFLIGHT_MAG_START = 1       # PREFLIGHT_CALIBRATION_MAGNETOMETER
PREFLIGHT_MAG_FORCE_SAVE = 76
COMPASS_ID = 0          # our single magnetometer
OUR_MASK = 1 << COMPASS_ID
FIXED_YAW_MAX_TURN_DEG = 2.0   # turn about the vertical within the averaging window above which a fixed yaw is refused:
                               # the field's mean is half the turn away from the heading given for now
FIXED_YAW_FIELD_MISMATCH_WARN_MGAUSS = 50.0   # the old model's |field| this far from the WMM's: soft iron may be stale

SEV_ERROR, SEV_WARNING, SEV_NOTICE, SEV_INFO = 3, 4, 5, 6   # MAV_SEVERITY


def field_config(settings: MagCalSettings, retry: bool, delay_s: float) -> FieldCalConfig:
    return FieldCalConfig(vehicle_type=VehicleType(settings.vehicle_type), fitness_mgauss=settings.fitness_mgauss,
                          timeout_s=settings.timeout_s, retry=retry, delay_s=delay_s,
                          course_min_speed_m_s=settings.course_min_speed_m_s)


class MagCalHost(Protocol):
    """What the handler needs from the daemon (`DaemonMagCalHost` below; tests provide a fake)."""

    def current_calibration(self): ...                 # Calibration in force
    # persist (atomic, previous kept) then hot-swap; raises if the save fails (the old one stays in force)
    def apply_calibration(self, cal) -> None: ...
    def send(self, msg) -> None: ...                    # to every endpoint
    def statustext(self, severity: int, text: str) -> None: ...    # any length, logged (daemon.outbound)
    def armed(self) -> bool: ...
    def reference_field(self, lat_deg: float | None = None, lon_deg: float | None = None): ...  # EarthField | None


class MagCalEstimate(Protocol):
    """What the field calibration reads of the estimator's attitude each sample (the pipeline's
    estimator/estimate_view.EstimateView has it; a test's fake declares the same)."""

    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    rate_body_rad_s: np.ndarray       # bias-corrected angular rate, body axes
    gyro_bias_rad_s: np.ndarray       # the fixed-yaw check counts the turn from the gyro less this


def sensor_attitude(estimate: MagCalEstimate | None, mounting: np.ndarray | None) -> FieldAttitude | None:
    """The estimator's body attitude re-expressed for the sensor axes (`sensor_frame`); None without one."""
    if estimate is None:
        return None
    return sensor_frame(float(estimate.roll_rad), float(estimate.pitch_rad), float(estimate.yaw_rad),
                        estimate.rate_body_rad_s, mounting)


def sensor_frame(roll_rad: float, pitch_rad: float, yaw_rad: float, rate_body_rad_s: np.ndarray,
                 mounting: np.ndarray | None) -> FieldAttitude:
    """A body attitude re-expressed for the sensor axes (C_sn = C_bn · M, M = body←sensor, None = identity):
    roll/pitch/yaw of the sensor frame, the angular rate in sensor axes and the body's yaw — what a session
    fitting sensor-frame data levels its magnetometer with."""
    if mounting is None:
        return FieldAttitude(roll_rad, pitch_rad, yaw_rad, rate_body_rad_s)
    c = euler_to_dcm(roll_rad, pitch_rad, yaw_rad) @ mounting
    return FieldAttitude(math.atan2(c[2, 1], c[2, 2]), -math.asin(max(-1.0, min(1.0, float(c[2, 0])))),
                         math.atan2(c[1, 0], c[0, 0]), mounting.T @ np.asarray(rate_body_rad_s, dtype=float),
                         body_yaw_rad=yaw_rad)


class MagCalProtocol:
    """Handlers for the mag-cal commands plus the periodic outputs. Call from the event loop only;
    fits run in a worker process (a thread where processes are not available) and are collected in `tick`."""

    def __init__(self, host: MagCalHost, settings: MagCalSettings | None = None, clock=time.monotonic, *,
                 warm_fit_worker: bool = True, fit_in_process: bool = True):
        self.host = host
        self.settings = settings or MagCalSettings()
        self.clock = clock
        # start the fit worker (and its imports) when a session starts, not at its first fit (False: a test whose
        # sessions never fit)
        self.warm_fit_worker = warm_fit_worker
        # False: fits in a thread, for a test of the handler on a fake host, where no sensor reader competes for
        # the GIL and a worker process (an interpreter start and the fits' imports) per session is what costs
        self.fit_in_process = fit_in_process
        self.session: FieldCalibration | None = None
        self.autosave = False
        self.saved = False
        self.last_result_saved = False   # the last session ended with its result saved, and none started since
        self._executor: concurrent.futures.ThreadPoolExecutor | None = None
        self._fit_future: concurrent.futures.Future | None = None
        self._next_progress = 0.0
        self._next_report = 0.0
        self._final_progress_sent = True     # no session yet
        self._recent_raw: deque = deque()
        self._last_estimate = None
        self._mounting: np.ndarray | None = None
        self._mask_requested = OUR_MASK
        self._last_sample_t: float | None = None
        self.course_fed = 0          # GNSS course fixes handed to a running session
        self.course_unusable = 0     # GNSS messages without a usable velocity (counted, not fed)
        self._gnss = MavlinkGnssSelector(use_fused=self.settings.course_from_global_position_int)

    # ------------------------------------------------------------------ wiring
    def register(self, router) -> None:
        """Install the command handlers in a daemon CommandRouter."""
        b = self.settings.accept_broadcast
        router.register(CMD_START, self.handle_start, accept_broadcast=b)
        router.register(CMD_ACCEPT, self.handle_accept, accept_broadcast=b)
        router.register(CMD_CANCEL, self.handle_cancel, accept_broadcast=b)
        router.register(CMD_FIXED_YAW, self.handle_fixed_yaw, accept_broadcast=b)
        if CMD_PREFLIGHT not in router.registered():
            router.register(CMD_PREFLIGHT, self.handle_preflight_mag, accept_broadcast=False)

    @property
    def calibrating(self) -> bool:
        return self.session is not None and self.session.status.running

    @property
    def system_status(self) -> int | None:
        """MAV_STATE for HEARTBEAT while a session runs (CALIBRATING), else None (the daemon's own)."""
        return mavlink.MAV_STATE_CALIBRATING if self.calibrating else None

    def close(self) -> None:
        self._release_worker()

    def _release_worker(self) -> None:
        """The fit worker process lives only while a session needs it."""
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = None

    # ------------------------------------------------------------------ per sample
    def on_sample(self, sample, estimate: MagCalEstimate | None, mounting: np.ndarray | None = None,
                  mag_model=None) -> None:
        """Every sample, calibrated with the calibration in force but in the SENSOR frame (calibrations are
        sensor-frame models: the pipeline calibrates before the mounting rotation), its estimate (body
        attitude), the mounting (body←sensor DCM, None = identity) and the magnetometer model that calibrated it
        (None: the host's calibration in force). Cheap when no session runs."""
        self._last_estimate = estimate
        self._mounting = mounting
        now = sample.t_s
        self._last_sample_t = now
        q = self._recent_raw
        # with the magnetometer model that calibrated it, so the raw field can be recovered later, and the sample
        # (its gyro and specific force tell a still vehicle: worked out only when a fixed yaw asks)
        q.append((now, sample, self.host.current_calibration().mag if mag_model is None else mag_model))
        while q and now - q[0][0] > self.settings.fixed_yaw_average_s:
            q.popleft()
        s = self.session
        if s is not None and s.status.running:
            s.add_sample(sample, sensor_attitude(estimate, mounting), now_s=self.clock())
            self._submit_requested_fit(s)

    def on_run(self, t_s, rows: np.ndarray, estimate, mag_model, mounting: np.ndarray | None = None) -> None:
        """`on_sample` for a run of samples while no session runs (the daemon's sample reader takes whole runs then:
        daemon.sample_reader.SampleListeners): t_s their times, rows their calibrated (n, 9) rows in the SENSOR frame
        (gyro, accel, mag), `estimate` the in-place estimate at the last, `mounting` as `on_sample`'s. What
        `on_sample` keeps of each sample, kept the same, in order."""
        self._last_estimate = estimate
        self._mounting = mounting
        q = self._recent_raw
        window_s = self.settings.fixed_yaw_average_s
        now = t_s[-1]
        # each sample kept as its calibrated row (what `_kept_vectors` reads); `on_sample` drops the oldest after each
        # append. When the run's last time is its latest (not NaN: max() of a list starting with NaN is NaN), one
        # trim after the run drops the same: what a trim at an earlier sample drops is as old to the last one too,
        # and the trims drop from the front only
        if now >= max(t_s):
            q.extend(zip(t_s, rows, itertools.repeat(mag_model)))
            while q and now - q[0][0] > window_s:
                q.popleft()
        else:
            for t, r in zip(t_s, rows):
                q.append((t, r, mag_model))
                while q and t - q[0][0] > window_s:
                    q.popleft()
        self._last_sample_t = now

    def _submit_requested_fit(self, s: FieldCalibration) -> None:
        """Hand a fit the session asked for to the worker at the sample that asked (its data end there).
        Left to the wall-clock tick, the session would keep taking samples until the next tick: up to tens of
        seconds of recording when the daemon catches up after a stall on a loaded machine."""
        if self._fit_future is None:
            job = s.pending_fit()
            if job is not None:
                # the data's span in the log: a session longer than its coverage needed shows here
                log.info("magcal: %s fit of %d samples, %.2f-%.2f s", job.stage, len(job.t),
                         job.t[0] if len(job.t) else math.nan, job.t[-1] if len(job.t) else math.nan)
                self._fit_future = self._submit(job)

    def on_gnss_message(self, msg) -> None:
        """The autopilot's GPS_RAW_INT (GLOBAL_POSITION_INT only with `course_from_global_position_int`),
        converted by drivers/gnss/mavlink.py and stamped with the time of validity on the samples' clock (the
        latest sample time minus `gnss_latency_s`): its course and speed go to a running session. Ignored
        while no session runs; messages without a usable velocity are counted."""
        s = self.session
        if s is None or not s.status.running or self._last_sample_t is None:
            return
        fix = self._gnss.handle(msg, self._last_sample_t - self.settings.gnss_latency_s)
        if fix is None:
            return          # a repeated GPS_RAW_INT, or GLOBAL_POSITION_INT not wanted (the selector counts them)
        if s.add_gnss_fix(fix):
            self.course_fed += 1
        else:
            self.course_unusable += 1

    @property
    def fit_running(self) -> bool:
        """A fit handed to the worker and not taken in yet (a tick takes it in once it is done)."""
        return self._fit_future is not None

    # ------------------------------------------------------------------ periodic
    def tick(self) -> None:
        """Call at ≥ 4 Hz: collects finished fits, streams progress/report, watches for arming."""
        now = self.clock()
        s = self.session
        if s is None:
            return
        if s.status.running and self.host.armed() and not self.settings.allow_armed:
            self._stop_session()
            self.host.statustext(SEV_WARNING, "Mag cal cancelled: vehicle armed")
            return
        s.tick(now)
        self._run_pending_fit(s)
        for sev, text in s.pop_messages():
            self.host.statustext(sev, text)
        if s.status == CalStatus.SUCCESS and self.autosave and not self.saved:
            self._accept_result()
        if s.status.running and now >= self._next_progress:
            self._next_progress = now + 1.0 / self.settings.progress_rate_hz
            self.host.send(self.progress_message())
        elif s.status.finished and now >= self._next_report:
            if not self._final_progress_sent:
                # progress goes out at a fixed rate, so the last one seen may be well short of the end: one more as
                # the session ends lets a ground station's bar finish (100 % on success) before the report
                self._final_progress_sent = True
                self.host.send(self.progress_message())
            self._next_report = now + 1.0 / self.settings.report_rate_hz
            self.host.send(self.report_message())

    def _run_pending_fit(self, s: FieldCalibration) -> None:
        fut = self._fit_future
        if fut is not None and fut.done():
            self._fit_future = None
            try:
                outcome = fut.result()
            except Exception as exc:  # noqa: BLE001 - reported as a failed calibration
                outcome = ("final", exc)
            s.fit_done(outcome)
            if not s.status.running:
                self._release_worker()
        if s.status.running:
            self._submit_requested_fit(s)

    def _warm_worker(self) -> None:
        """Start the fit worker (and its imports) while the operator is still turning."""
        try:
            self._submit(_warm_up)
        except Exception as exc:  # noqa: BLE001 - the fit will start the worker later
            log.debug("magcal: worker warm-up failed: %s", exc)

    def _submit(self, job) -> concurrent.futures.Future:
        """Run a fit in a worker process (a long fit in a thread would hold the GIL and starve the sensor
        reader); fall back to a thread where processes are not available."""
        if self._executor is None and not self.fit_in_process:
            self._executor = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="magcal-fit")
        if self._executor is None:
            try:
                import multiprocessing

                self._executor = concurrent.futures.ProcessPoolExecutor(
                    1, mp_context=multiprocessing.get_context("spawn"))
            except (OSError, ValueError, ImportError) as exc:
                log.warning("magcal: no worker process (%s): fitting in a thread", exc)
                self._executor = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="magcal-fit")
        try:
            return self._executor.submit(job)
        except (concurrent.futures.process.BrokenProcessPool, RuntimeError, OSError) as exc:
            log.warning("magcal: worker process failed (%s): fitting in a thread", exc)
            self._executor = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="magcal-fit")
            return self._executor.submit(job)

    # ------------------------------------------------------------------ messages
    def progress_message(self):
        s = self.session
        d = s.direction_hint()
        return mavlink.MAVLink_mag_cal_progress_message(
            COMPASS_ID, OUR_MASK, int(s.status), max(1, s.attempt), s.completion_pct, list(s.completion_mask),
            float(d[0]), float(d[1]), float(d[2]))

    def report_message(self):
        s = self.session
        res = s.result
        if res is None:  # failed before any fit (timeout, no samples)
            zeros = (0.0, 0.0, 0.0)
            return mavlink.MAVLink_mag_cal_report_message(
                COMPASS_ID, OUR_MASK, int(s.status), 0, float("nan"), *zeros, 1.0, 1.0, 1.0, *zeros, 0.0, 0, 0, 0.0)
        ap = res.ardupilot
        return mavlink.MAVLink_mag_cal_report_message(
            COMPASS_ID, OUR_MASK, int(s.status), int(self.saved), float(res.fitness_mgauss),
            *(float(v) for v in ap.ofs_mgauss), *(float(v) for v in ap.diag), *(float(v) for v in ap.offdiag),
            0.0, 0, 0, float(ap.scale_factor))

    # ------------------------------------------------------------------ command handlers: (msg, ctx) -> MAV_RESULT
    def handle_start(self, msg, ctx=None) -> int:
        return self._start(CommandArgs.of(msg))

    def _start(self, args: CommandArgs) -> int:
        """DO_START_MAG_CAL's parameters (also PREFLIGHT_CALIBRATION's magnetometer start, as ArduPilot maps it)."""
        mask_f, retry_f, autosave_f, delay_s, autoreboot_f = args.params[:5]
        mask = whole_number(mask_f, 0, 255)
        flags = [whole_number(v, 0, 1) for v in (retry_f, autosave_f, autoreboot_f)]
        if mask is None:
            return Refused(mavlink.MAV_RESULT_FAILED, f"DO_START_MAG_CAL: mask {mask_f} not in 0..255")
        if None in flags:
            return Refused(mavlink.MAV_RESULT_FAILED, "DO_START_MAG_CAL: retry/autosave/autoreboot not 0/1")
        if not (math.isfinite(delay_s) and 0.0 <= delay_s <= self.settings.timeout_s):
            return Refused(mavlink.MAV_RESULT_FAILED, f"DO_START_MAG_CAL: delay {delay_s} s invalid")
        retry, autosave, autoreboot = (bool(f) for f in flags)
        if mask != 0 and not mask & OUR_MASK:
            return Refused(mavlink.MAV_RESULT_FAILED, f"Mag cal: no compass in mask {mask} (ours: compass 0)")
        if self._refused_while_armed():
            return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
        if self.calibrating:
            self.host.statustext(SEV_INFO, f"Mag cal already running ({self.session.completion_pct}%)")
            return mavlink.MAV_RESULT_ACCEPTED
        try:
            current = self.host.current_calibration()
            reference = self.host.reference_field()
        except Exception as exc:  # noqa: BLE001
            log.exception("cannot start magnetometer calibration")
            self.host.statustext(SEV_ERROR, f"Mag cal cannot start: {exc}")
            return mavlink.MAV_RESULT_FAILED
        if reference is None:
            self.host.statustext(SEV_WARNING, "Mag cal: no position for WMM: offsets only on level turns")
        self._stop_session()
        self.session = FieldCalibration(current, field_config(self.settings, retry, delay_s), reference,
                                        samples_are_calibrated=True, auto_fit=False)
        self.session.start()
        if self.warm_fit_worker:
            self._warm_worker()
        self.autosave, self.saved, self.last_result_saved = autosave, False, False
        self._mask_requested = mask or OUR_MASK
        self._next_progress = 0.0
        self._final_progress_sent = False
        if autoreboot:
            log.info("magcal: autoreboot requested: not needed, the new calibration is applied without a reboot")
        self.host.statustext(SEV_INFO, "Mag cal started" + (f", waiting {delay_s:.0f} s" if delay_s > 0 else ""))
        return mavlink.MAV_RESULT_ACCEPTED

    def handle_accept(self, msg, ctx=None) -> int:
        return self._accept(CommandArgs.of(msg).p(1))

    def _accept(self, mask_f: float) -> int:
        """DO_ACCEPT_MAG_CAL's compass mask (also PREFLIGHT_CALIBRATION's force-save, mask 0: every compass)."""
        if whole_number(mask_f, 0, 255) is None:
            return Refused(mavlink.MAV_RESULT_FAILED, f"DO_ACCEPT_MAG_CAL: mask {mask_f} not in 0..255")
        mask = int(mask_f) or 0xFF
        if not mask & OUR_MASK:
            return Refused(mavlink.MAV_RESULT_FAILED, f"Mag cal: no compass in mask {mask} (ours: compass 0)")
        s = self.session
        if s is None or s.status == CalStatus.NOT_STARTED:
            if self.last_result_saved:
                return mavlink.MAV_RESULT_ACCEPTED       # saved already: the accept was sent again
            self.host.statustext(SEV_NOTICE, "Mag cal: nothing to accept (no finished calibration): unchanged")
            return mavlink.MAV_RESULT_FAILED
        if s.status.running:
            self.host.statustext(SEV_NOTICE, f"Mag cal not finished ({s.completion_pct}%): keep turning")
            return mavlink.MAV_RESULT_FAILED
        if s.status != CalStatus.SUCCESS:
            self._stop_session()
            return mavlink.MAV_RESULT_FAILED
        ok = self.saved or self._accept_result()
        self._stop_session()
        self.last_result_saved = ok
        return mavlink.MAV_RESULT_ACCEPTED if ok else mavlink.MAV_RESULT_FAILED

    def handle_cancel(self, msg, ctx=None) -> int:
        mask_f = CommandArgs.of(msg).p(1)
        if whole_number(mask_f, 0, 255) is None:
            return Refused(mavlink.MAV_RESULT_FAILED, f"DO_CANCEL_MAG_CAL: mask {mask_f} not in 0..255")
        mask = int(mask_f) or 0xFF
        if mask & OUR_MASK and self.session is not None:
            s = self.session
            unsaved_result = s.status == CalStatus.SUCCESS and not self.saved
            was_running = self.calibrating
            self._stop_session()
            if was_running:
                self.host.statustext(SEV_INFO, "Mag cal cancelled")
            elif unsaved_result:
                self.host.statustext(SEV_INFO, "Mag cal cancelled: result dropped, calibration unchanged")
        return mavlink.MAV_RESULT_ACCEPTED

    def handle_preflight_mag(self, msg, ctx=None) -> int:
        p2 = CommandArgs.of(msg).p(2)
        if p2 == PREFLIGHT_MAG_START:    # every compass, no retry, autosave, no delay (docs/magcal-field.md)
            return self._start(CommandArgs(CMD_START, False, (0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0)))
        if p2 == PREFLIGHT_MAG_FORCE_SAVE:
            return self._accept(0.0)
        return mavlink.MAV_RESULT_UNSUPPORTED

    def handle_fixed_yaw(self, msg, ctx=None) -> int:
        """MAV_CMD_FIXED_MAG_CAL_YAW: the vehicle's true heading is yaw_deg now. With a finished, unsaved session:
        its heading offset from it; else the hard iron that makes the calibrated field point so (saved at once)."""
        request = _fixed_yaw_request(CommandArgs.of(msg))
        if isinstance(request, Refused):
            return request
        yaw_deg, lat, lon = request
        not_ready = self._not_ready_for_fixed_yaw()
        if not_ready is not None:
            return not_ready
        reference = self.host.reference_field(lat, lon) if (lat or lon) else self.host.reference_field()
        if reference is None:
            self.host.statustext(SEV_ERROR, "Mag: no position available")
            return mavlink.MAV_RESULT_FAILED
        raw_mean = self._raw_mag_mean_ut()
        est = self._last_estimate
        # the fit is in the sensor frame: the attitude of the sensor axes for the body's given true heading
        sensor = sensor_frame(float(est.roll_rad), float(est.pitch_rad), math.radians(float(yaw_deg)), np.zeros(3),
                              self._mounting)
        s = self.session
        if s is not None and s.status == CalStatus.SUCCESS and not self.saved:
            return self._known_heading_offset(s, raw_mean, sensor, reference)
        return self._fixed_yaw_hard_iron(yaw_deg, raw_mean, sensor, reference)

    def _refused_while_armed(self) -> bool:
        """The autopilot reports armed and a calibration is not allowed then (`allow_armed`): said to the operator."""
        if self.host.armed() and not self.settings.allow_armed:
            self.host.statustext(SEV_NOTICE, "Disarm to allow compass calibration")
            return True
        return False

    def _not_ready_for_fixed_yaw(self) -> int | None:
        """Why a fixed-yaw calibration cannot run now (said to the operator), as the result to answer; None: it can."""
        if self._refused_while_armed():
            return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
        if self.calibrating:
            self.host.statustext(SEV_NOTICE, "Mag cal running: cancel it before a fixed-yaw cal")
            return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
        if self._last_estimate is None or not self._recent_raw:
            self.host.statustext(SEV_ERROR, "Mag: no attitude yet for fixed-yaw cal")
            return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
        turned_deg = self._turned_in_window_deg()
        if turned_deg > FIXED_YAW_MAX_TURN_DEG:
            self.host.statustext(SEV_NOTICE, f"Mag: turned {turned_deg:.0f} deg in the last "
                                             f"{self.settings.fixed_yaw_average_s:g} s: hold it still on the known "
                                             "heading for fixed-yaw cal")
            return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
        return None

    def _turned_in_window_deg(self) -> float:
        """|heading change| over the fixed-yaw averaging window, from the gyro about the vertical less the
        estimator's gyro bias (an uncalibrated ADIS16405 may read up to 3 °/s still: data sheet)."""
        bias = np.asarray(self._last_estimate.gyro_bias_rad_s, dtype=float)
        if not np.all(np.isfinite(bias)):
            bias = np.zeros(3)
        if self._mounting is not None:
            bias = self._mounting.T @ bias          # body axes -> sensor axes (the samples')
        q = self._recent_raw
        turned = sum((t1 - t0) * _rate_about_vertical_rad_s(*_kept_vectors(kept)[:2], bias)
                     for (t0, *_), (t1, kept, _model) in zip(q, list(q)[1:]))
        return abs(math.degrees(turned))

    def _fixed_yaw_hard_iron(self, yaw_deg: float, raw_mean, sensor, reference) -> int:
        """The calibration in force with the hard iron the known heading gives (soft iron kept), saved and swapped
        in; a warning when the old model's field strength is far from the WMM's (its soft iron may be stale)."""
        current = self.host.current_calibration()
        res = fixed_yaw_calibration(math.degrees(sensor.yaw_rad), reference, sensor.roll_rad, sensor.pitch_rad,
                                    raw_mean, current.mag)
        new = current.with_sensor("mag", res.model, method="field:fixed-yaw", true_heading_deg=float(yaw_deg),
                                  before={"hard_iron_ut": current.mag.hard_iron_ut.tolist(),
                                          "soft_iron": current.mag.soft_iron.tolist()})
        if not self._save_and_swap(new, current, res.message):
            return mavlink.MAV_RESULT_FAILED
        mismatch_mgauss = res.field_mismatch_ut * UT_TO_MGAUSS
        if mismatch_mgauss > FIXED_YAW_FIELD_MISMATCH_WARN_MGAUSS:
            self.host.statustext(SEV_WARNING, f"Mag field {mismatch_mgauss:.0f} mG off WMM: "
                                   "soft iron may be stale, run a full cal")
        return mavlink.MAV_RESULT_ACCEPTED

    def _known_heading_offset(self, s: FieldCalibration, raw_mean, sensor, reference) -> int:
        """A finished session's result, not saved yet, and a known true heading: the constant heading offset
        (the swing fit's A) of the result is set from it, soft and hard iron otherwise kept; accept saves."""
        measured = tilt_compensated_heading_rad(s.result.model.apply(raw_mean), sensor.roll_rad, sensor.pitch_rad)
        offset = float(wrap_180_deg(math.degrees(sensor.yaw_rad - float(measured[0]) - reference.declination_rad)))
        if not s.set_heading_offset(offset, "known heading"):
            return mavlink.MAV_RESULT_FAILED
        self.host.statustext(SEV_NOTICE,
                             f"Mag cal: heading offset {offset:+.1f} deg from the known heading. Accept to save")
        return mavlink.MAV_RESULT_ACCEPTED
    def _raw_mag_mean_ut(self) -> np.ndarray:
        """Mean raw (uncalibrated) field of the recent samples: each sample's own calibration undone
        (raw = W⁻¹·m + h), so a calibration swapped in meanwhile — a fixed-yaw request a moment ago — does
        not enter the result twice."""
        by_model: dict[int, tuple[Any, list]] = {}
        for _t, kept, model in self._recent_raw:
            mag_ut = _kept_vectors(kept)[2]
            by_model.setdefault(id(model), (model, []))[1].append(mag_ut)
        total = np.zeros(3)
        for model, mags in by_model.values():
            cal = np.asarray(mags, dtype=np.float64)
            total += np.linalg.solve(model.soft_iron, cal.T).sum(axis=1) + len(mags) * model.hard_iron_ut
        return total / len(self._recent_raw)

    # ------------------------------------------------------------------ accept / save
    def _accept_result(self) -> bool:
        s = self.session
        res = s.result
        current = self.host.current_calibration()
        new = res.proposed_calibration(current)
        text = (f"Mag cal saved: ofs {np.round(res.ardupilot.ofs_mgauss).astype(int).tolist()} mG, "
                f"fitness {res.fitness_mgauss:.1f} mG, {res.method}")
        ok = self._save_and_swap(new, current, text, res.describe_change())
        self.saved = ok
        return ok

    def _save_and_swap(self, new, current, text: str, log_line: str | None = None) -> bool:
        try:
            self.host.apply_calibration(new)
        except Exception as exc:  # noqa: BLE001 - the previous calibration stays in force and on disk
            log.exception("saving the new magnetometer calibration failed")
            self.host.statustext(SEV_ERROR, f"Mag cal save failed: {exc}")
            return False
        log.warning("magnetometer calibration changed: %s", log_line or text)
        log.warning("  before: hard_iron_ut=%s soft_iron=%s", np.round(current.mag.hard_iron_ut, 3).tolist(),
                    np.round(current.mag.soft_iron, 5).tolist())
        log.warning("  after:  hard_iron_ut=%s soft_iron=%s", np.round(new.mag.hard_iron_ut, 3).tolist(),
                    np.round(new.mag.soft_iron, 5).tolist())
        self.host.statustext(SEV_NOTICE, text)
        return True

    def _stop_session(self) -> None:
        if self.session is not None:
            self.session.cancel()
        self.session = None
        if self._fit_future is not None:
            self._fit_future.cancel()
            self._fit_future = None
        self._release_worker()
        self.saved = False


def _warm_up() -> None:
    """Runs in the fit worker: import what the fits need."""
    import ahrsd.calibration.mag.backstepping  # noqa: F401
    import ahrsd.calibration.mag.ellipsoid  # noqa: F401
    import ahrsd.calibration.mag.fit  # noqa: F401



def _kept_vectors(kept) -> tuple:
    """(gyro, accel, mag) of a sample the protocol keeps: its ImuSample (`on_sample`) or its calibrated (9,) row
    (`on_run`)."""
    if type(kept) is np.ndarray:
        return kept[0:3], kept[3:6], kept[6:9]
    return kept.gyro_rad_s, kept.accel_m_s2, kept.mag_ut


def _rate_about_vertical_rad_s(gyro_rad_s, accel_m_s2, gyro_bias_rad_s: np.ndarray) -> float:
    """The gyro's rate, less its bias, about the specific force's direction (the vertical at rest); 0 when either
    is not finite."""
    f = np.asarray(accel_m_s2, dtype=float)
    norm = float(np.linalg.norm(f))
    if not math.isfinite(norm) or norm < 1.0:
        return 0.0
    rate = float(np.dot(np.asarray(gyro_rad_s, dtype=float) - gyro_bias_rad_s, f) / norm)
    return rate if math.isfinite(rate) else 0.0


def _fixed_yaw_request(args: CommandArgs) -> tuple[float, float, float] | Refused:
    """MAV_CMD_FIXED_MAG_CAL_YAW's (yaw_deg, lat, lon) — lat = lon = 0: no position given — or why it is refused:
    param1 yaw, param2 compass mask, param3/4 lat/lon (COMMAND_INT: x/y in degE7 instead, in a global frame)."""
    yaw_deg, mask_f, lat, lon = args.params[:4]
    mask = whole_number(mask_f, 0, 255)
    if mask is None or (mask and not mask & OUR_MASK):
        return Refused(mavlink.MAV_RESULT_FAILED, f"FIXED_MAG_CAL_YAW: no compass of ours in mask {mask_f}")
    if not (math.isfinite(yaw_deg) and -360.0 <= yaw_deg <= 360.0):
        return Refused(mavlink.MAV_RESULT_DENIED, f"FIXED_MAG_CAL_YAW: yaw {yaw_deg} deg invalid")
    int_position = args.int_position_deg()     # COMMAND_INT: a position travels as x/y, degE7
    if int_position is not None:
        if not args.position_frame_ok:
            return Refused(mavlink.MAV_RESULT_DENIED, f"FIXED_MAG_CAL_YAW: frame {args.frame} not global")
        if not (lat == 0 and lon == 0):
            return Refused(mavlink.MAV_RESULT_DENIED, "FIXED_MAG_CAL_YAW: position in both param3/4 and x/y")
        lat, lon = int_position
    problem = None if (lat == 0 and lon == 0) else position_problem(lat, lon)
    if problem:
        return Refused(mavlink.MAV_RESULT_DENIED, f"FIXED_MAG_CAL_YAW: {problem}")
    return yaw_deg, lat, lon


# ============================================================================ the daemon adapter


class DaemonMagCalHost:
    """`MagCalHost` on the daemon's parts, each given explicitly: the pipeline (calibration in force, sensor-frame
    sample, mounting), the one calibration path (daemon.calibration_swap), the outbound link, the autopilot
    (armed), the position resolver (daemon.position: the reference field) and the heading slew (a swap has
    fully arrived when it ends)."""

    def __init__(self, pipeline, swap: CalibrationSwap, outbound: Outbound, autopilot: AutopilotState,
                 positions: PositionResolver, slew: HeadingSlew):
        self.pipeline = pipeline
        self.swap = swap
        self.outbound = outbound
        self.autopilot = autopilot
        self.positions = positions
        self.slew = slew
        self.applying = False            # a swap whose heading slew has not finished yet

    def current_calibration(self):
        return self.pipeline.calibration

    def apply_calibration(self, cal) -> None:
        """Save and swap through the daemon's one calibration path (store, estimator, heading slew)."""
        self.swap.apply(cal, save=True, reason="magnetometer calibration")
        self.applying = True

    def send(self, msg) -> None:
        self.outbound.send(msg)

    def statustext(self, severity: int, text: str) -> None:
        self.outbound.statustext(severity, text)

    def armed(self) -> bool:
        return bool(self.autopilot.armed)

    def reference_field(self, lat_deg: float | None = None, lon_deg: float | None = None):
        """The WMM field at the position the request gives, else at daemon.position's (the declination's); a
        remembered position is said (`ahrsd magcal` shows it): the vehicle may have moved since."""
        if lat_deg or lon_deg:
            return earth_field(float(lat_deg), float(lon_deg))
        position = self.positions.position()
        if position is None:
            return None
        if position.source == "remembered":
            self.statustext(SEV_INFO, f"Mag cal: reference field at the position {position.describe()}")
        return position.earth_field()


class FieldCalibrationPart:
    """The field magnetometer calibration in the daemon: the protocol handler (`protocol`, its commands
    registered in the router), fed every sample (`on_sample`, a sample listener) and the autopilot's GPS
    messages (an AutopilotState listener), ticked by its own loop callback; it reports CALIBRATING through
    `set_calibrating(text)`."""

    def __init__(self, host: DaemonMagCalHost, settings: MagCalSettings, *, commands, autopilot: AutopilotState,
                 set_calibrating, clock=time.monotonic, warm_fit_worker: bool = True):
        self.host = host
        self.protocol = MagCalProtocol(host, settings, clock, warm_fit_worker=warm_fit_worker)
        self.set_calibrating = set_calibrating
        self._tick_handle: asyncio.Handle | None = None
        self._calibrating_shown = False
        self.protocol.register(commands)
        autopilot.add_gnss_listener(self.protocol.on_gnss_message)

    def steps_ahead(self) -> bool:
        """The listener's word to the daemon's sample reader (sample_reader.SampleListeners): while no session runs
        it keeps the in-place estimate without reading it (a fixed-yaw calibration reads it later, between
        blocks) and swaps no calibration at a sample, so the estimator may step a run of samples before it."""
        return not self.protocol.calibrating

    def takes_runs(self) -> bool:
        """The listener takes a run of samples in one call (`on_run`) now: while no session runs (when it lets the
        estimator step ahead)."""
        return self.steps_ahead()

    def on_run(self, t_s, rows, estimate) -> None:
        """`on_sample` for a run of samples (daemon.sample_reader.SampleListeners `runs=`, while `takes_runs`): the
        run's rows in the sensor frame (the pipeline's body-frame rows without a mounting, else its sensor-frame
        rows of the run, each the sample `last_sensor_sample` gives)."""
        pipeline = self.host.pipeline
        mounting = pipeline.mounting
        self.protocol.on_run(t_s, rows if mounting is None else pipeline.run_sensor_rows(), estimate,
                             pipeline.calibration.mag, mounting)
        if self._tick_handle is None:
            self._tick_handle = asyncio.get_running_loop().call_soon(self._tick_and_rearm)

    def on_sample(self, sample, estimate) -> None:
        """The daemon's sample listener (event loop, every sample; added in place: `estimate` is read in place,
        daemon.sample_reader.SampleListeners). The session fits in the sensor frame, so it gets the pipeline's
        calibrated sample before the mounting rotation, and the mounting. A running session gets every sample's
        immutable estimate; otherwise the protocol keeps the in-place one (a fixed-yaw calibration reads the
        latest attitude from it) and no estimate is built."""
        # every sample (819.2 a second): the pipeline's attributes read directly, not through the properties and
        # the host's calls that say the same (`calibrating`, `last_sensor_sample` — the sample itself without a
        # mounting —, `current_calibration`), one Python call in all instead of five
        pipeline = self.host.pipeline
        protocol = self.protocol
        session = protocol.session
        if session is not None and session.status.running:
            estimate = pipeline.last_estimate
        mounting = pipeline.mounting
        protocol.on_sample(sample if mounting is None else pipeline.last_sensor_sample, estimate, mounting,
                           pipeline.calibration.mag)
        if self._tick_handle is None:
            self._tick_handle = asyncio.get_running_loop().call_soon(self._tick_and_rearm)

    def tick(self) -> None:
        self.protocol.tick()
        if self.host.applying and not self.host.slew.active:
            self.host.applying = False
            self.host.statustext(SEV_INFO, "Mag cal: new calibration fully applied")
        calibrating = self.protocol.calibrating
        if calibrating != self._calibrating_shown:
            self._calibrating_shown = calibrating
            self.set_calibrating("magnetometer calibration" if calibrating else "")

    def _tick_and_rearm(self) -> None:
        """The part's ticker, from the first sample on: a loop callback that re-arms itself (`call_later`), not a
        task resumed by `asyncio.sleep`, which costs the event loop two wakes a tick instead of one."""
        try:
            self.tick()
        except Exception:  # noqa: BLE001 - the calibration must never stop the daemon
            log.exception("magcal tick failed")
        period_s = 1.0 / max(10.0, 2.5 * self.protocol.settings.progress_rate_hz)
        self._tick_handle = asyncio.get_running_loop().call_later(period_s, self._tick_and_rearm)

    def close(self) -> None:
        if self._tick_handle is not None:
            self._tick_handle.cancel()
        self.protocol.close()
