"""Field magnetometer recalibration: the session a ground station drives, independent of MAVLink.

`FieldCalibration` is fed samples (raw or already calibrated with the calibration in force) together with
the estimator's attitude. It tracks coverage the way ArduPilot's `CompassCalibrator` does (an 80-cell
completion mask over the sphere of corrected field directions, `AP_GeodesicGrid` sections) and, for vehicles
that cannot be tumbled, the coverage of headings; it reports completion %, a direction hint and the
MAVLink `MAG_CAL_STATUS` states, then picks the fit from the data:

- WMM reference known (level turns or a tumble) -> back-stepping / vertical-channel fit (`fit_mag("backstepping")`),
                                                    the same call and data path as `ahrsd calibrate mag`; it also
                                                    sees the rotation part of the soft iron an ellipsoid cannot
- full sphere seen, no reference                 -> 9-parameter ellipsoid (`fit_mag("ellipsoid")`)
- the fit's own observability analysis says it   -> hard iron only, soft iron kept from the calibration in
  does not beat offsets-only (or it refused)        force ("…: fitted offsets only")

The choice between the full fit and offsets-only is made from the fit's parameter covariance
(observability.compare_with_offsets): the full result is used when its predicted heading error is smaller
than the heading change it makes relative to the offsets-only model. With GNSS course over ground fed to the
session (`add_course`, `add_gnss_fix`) the constant heading offset (the swing fit's A) is fitted from course vs
heading on straight runs (course_offset.py) and folded into the soft iron.

and judges the result against ArduPilot's acceptance rules (fitness = RMS field-magnitude residual in
mgauss vs `COMPASS_CAL_FIT`, offsets, diagonals, radius). The result is a proposed `Calibration` with the
before/after parameters; accepting it (saving and hot-swapping) is the daemon's job (daemon/magcal.py).

The parts it uses live beside it: the completion mask in `geodesic_grid.py`, ArduPilot's conventions and
acceptance limits in `ardupilot_compass.py`, the offsets-only fit in `mag/offsets.py`.

Time: every duration in the session (start delay, timeout) is measured in *sample* time (`sample.t_s`), so
a simulation running faster than real time behaves like the real thing; only the "no samples arriving"
check uses the caller's wall clock (`tick(now_s)`).
"""

from __future__ import annotations

import dataclasses
import enum
import logging
import math
import threading
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from ahrsd.core.angles import roll_pitch_from_accel, tilt_compensated_heading_rad, wrap_pi, yaw_rate_ned_rad_s

from .ardupilot_compass import (COMPASS_CAL_FIT_DEFAULT_MGAUSS, COMPASS_OFFS_MAX_MGAUSS, DIAG_MAX, DIAG_MIN,
                                MAX_SCALE_FACTOR, OFFDIAG_MAX, RADIUS_MAX_MGAUSS, RADIUS_MIN_MGAUSS, UT_TO_MGAUSS,
                                ArduPilotMagParams, to_ardupilot)
from .mag.geodesic_grid import N_SECTIONS, completion_mask_bytes, geodesic_section, geodesic_sections, section_centres
from .mag.backstepping import fold_heading_offset
from .mag.backstepping_paper import magnetic_heading_deg
from .mag.course_offset import (DEFAULT_MAX_TURN_RATE_DEG_S, DEFAULT_STRAIGHT_WINDOW_S, CourseOffsetFit,
                            fit_course_offset)
from .mag.offsets import fit_offsets_keep_soft_iron
from .mag.fit import fit_mag
from .mag.fit_types import MagFitInput
from .mag.levelling_error import frame_tilt_heading_std_deg, frame_tilt_sigma_deg
from .heading_trust import calibration_heading_sigma_rad
from .models import Calibration, MagModel
from .mag.observability import algebraic_sphere_centre, compare_with_offsets
from .mag.swing import DEFAULT_MIN_SPEED_M_S

if TYPE_CHECKING:  # pragma: no cover
    from ahrsd.core.gnss import GnssFix
    from ahrsd.core.sample import ImuSample
    from ahrsd.core.wmm import EarthField

log = logging.getLogger(__name__)

class CalStatus(enum.IntEnum):
    """MAVLink MAG_CAL_STATUS (ardupilotmega.xml / common.xml, pymavlink 2.4.50)."""

    NOT_STARTED = 0
    WAITING_TO_START = 1
    RUNNING_STEP_ONE = 2
    RUNNING_STEP_TWO = 3
    SUCCESS = 4
    FAILED = 5
    BAD_ORIENTATION = 6
    BAD_RADIUS = 7
    FAILED_OFFSETS = 8
    FAILED_DIAG_SCALING = 9
    FAILED_RESIDUALS_HIGH = 10

    @property
    def running(self) -> bool:
        return self in (CalStatus.WAITING_TO_START, CalStatus.RUNNING_STEP_ONE, CalStatus.RUNNING_STEP_TWO)

    @property
    def finished(self) -> bool:
        return self >= CalStatus.SUCCESS


# ============================================================================ the session


class VehicleType(str, enum.Enum):
    AUTO = "auto"      # decide from the data (tilt seen)
    LEVEL = "level"    # cannot be tumbled: boat, rover, AUV at the surface, large vehicle
    TUMBLE = "tumble"  # can be rotated through the full sphere: small drone, handheld


@dataclass(frozen=True)
class FieldAttitude:
    """The attitude a session levels a sample with, in the magnetometer's (sensor) axes: ZYX Euler angles; the
    angular rate in those axes, from which the heading coverage counts how far the vehicle turned (None: the
    coverage follows `yaw_rad` itself); the body's yaw when the sensor is mounted turned in the body (None: the
    body's yaw is `yaw_rad`). daemon.magcal builds it from the estimator's attitude and the mounting."""

    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    rate_rad_s: np.ndarray | None = None
    body_yaw_rad: float | None = None


@dataclass(frozen=True)
class FieldCalConfig:
    """Settings of a field recalibration. Units in the names; defaults in the comments' sources."""

    vehicle_type: VehicleType = VehicleType.AUTO
    fitness_mgauss: float = COMPASS_CAL_FIT_DEFAULT_MGAUSS   # ArduPilot COMPASS_CAL_FIT default
    offsets_max_mgauss: float = COMPASS_OFFS_MAX_MGAUSS      # ArduPilot COMPASS_OFFS_MAX default
    delay_s: float = 0.0                                     # MAV_CMD_DO_START_MAG_CAL p4
    retry: bool = False                                      # p2
    timeout_s: float = 300.0          # sample time allowed from start to complete coverage
    no_sample_timeout_s: float = 2.0  # wall clock without samples -> FAILED (ArduPilot: 1 s)
    store_rate_hz: float = 20.0       # samples kept per second (the rest only feed the attitude)
    capacity: int = 8192              # samples kept at most (decimated by 2 when full)
    heading_sectors: int = 36         # 10° sectors for level vehicles
    samples_per_sector: int = 3
    sphere_target: float = 0.75       # fraction of the 80 cells for a tumbled vehicle (ArduPilot ≈ 300 spread samples)
    # AUTO: tilt beyond this means "being tumbled" -> sphere coverage needed. A boat in a sea or an AUV rolls
    # ±30° and more but never tumbles; the 80-cell sphere mask cannot fill on such a vehicle.
    tumble_tilt_deg: float = 60.0
    validation_fraction: float = 1 / 3  # step two: fresh coverage (fraction of step one's): more data, checked fit
    course_min_speed_m_s: float = DEFAULT_MIN_SPEED_M_S              # GNSS course used above this ground speed
    course_max_turn_rate_deg_s: float = DEFAULT_MAX_TURN_RATE_DEG_S  # …on straight runs (heading rate below this)
    course_window_s: float = DEFAULT_STRAIGHT_WINDOW_S               # …for this long around the fix
    course_capacity: int = 4096       # GNSS course fixes kept at most
    # a tilt-based constant heading offset known worse than this is reported with the hint that a GNSS course or
    # a fixed-yaw command would set it better; it keeps its stated 1σ (covers the error: docs/magcal-field.md)
    max_offset_std_deg: float = 0.5


@dataclass(frozen=True)
class FieldCalResult:
    status: CalStatus
    reason: str
    method: str
    model: MagModel
    before: MagModel
    fitness_mgauss: float
    quality: dict
    ardupilot: ArduPilotMagParams
    partial: bool = False  # True when only the hard iron was fitted
    heading_std_deg: float = math.nan  # predicted 1σ of the heading-dependent error (within the tilt envelope)
    offset_std_deg: float = math.nan   # 1σ of the constant heading offset (math.inf: undetermined)
    # "GNSS course", "tilt", "calibration in force", "known heading"; "undetermined" exactly when offset_std_deg
    # is not finite (stored as null: the heading is unknown after accepting, calibration/heading_trust.py)
    offset_source: str = ""
    undetermined: tuple = ()           # parameters the data could not determine
    # the levelling's body-fixed tilt (1σ per axis) and its share of heading_std_deg (tan(dip) times it), as `ahrsd
    # calibrate mag` states them (levelling_error.py): the back-stepping fit is levelled by the accelerometer, its
    # bias over g; NaN: none stated (offsets only, the ellipsoid), ins then takes the frame as the body's
    frame_tilt_std_deg: float = math.nan
    frame_tilt_heading_std_deg: float = math.nan

    def accuracy_text(self) -> str:
        """One line for a person: the predicted heading accuracy and what the offset rests on."""
        def deg(x: float) -> str:
            return f"{x:.2f}" if x < 0.095 else f"{x:.1f}"

        dep = f"heading +-{deg(self.heading_std_deg)} deg" if math.isfinite(self.heading_std_deg) else "heading accuracy unknown"
        if self.offset_source == "undetermined":
            off = "offset undetermined: no usable GNSS course (a fixed-yaw command sets it)"
        elif math.isfinite(self.offset_std_deg):
            off = f"offset +-{deg(self.offset_std_deg)} deg ({self.offset_source})"
            if self.offset_source == "tilt" and self.quality.get("offset_weakly_determined"):
                # weakly determined by the tilt alone: still a stated figure the daemon uses, never "undetermined"
                off += ", no usable GNSS course (a fixed-yaw command sets it better)"
        else:
            off = f"offset from {self.offset_source}"
        return f"Mag cal: {dep}, {off}"

    def proposed_calibration(self, current: Calibration) -> Calibration:
        # the frame's tilt only when stated (calibration/heading_trust.py reads its absence as none)
        frame_tilt = {key: float(value) for key, value in (("frame_tilt_std_deg", self.frame_tilt_std_deg),
                                                           ("frame_tilt_heading_std_deg", self.frame_tilt_heading_std_deg))
                      if math.isfinite(value)}
        return current.with_sensor(
            "mag",
            self.model,
            method=f"field:{self.method}",
            residual_rms_mgauss=self.fitness_mgauss,
            partial=self.partial,
            heading_std_deg=_finite_or_none(self.heading_std_deg), offset_std_deg=_finite_or_none(self.offset_std_deg),
            offset_source=self.offset_source, undetermined=list(self.undetermined),
            data_span_s=self.quality.get("t_span_s"),
            before={"hard_iron_ut": self.before.hard_iron_ut.tolist(), "soft_iron": self.before.soft_iron.tolist()},
            **frame_tilt,
        )

    def describe_change(self) -> str:
        """One log line with before/after parameters (µT, matrix rows)."""
        b, a = self.before, self.model
        return (
            f"mag calibration {self.method}: hard iron {np.round(b.hard_iron_ut, 2).tolist()} -> "
            f"{np.round(a.hard_iron_ut, 2).tolist()} uT; soft iron {np.round(b.soft_iron, 4).tolist()} -> "
            f"{np.round(a.soft_iron, 4).tolist()}; fitness {self.fitness_mgauss:.1f} mG"
        )


FitFunction = Callable[..., Any]  # mag.fit.fit_mag's signature
SPHERE_RECENTRE_EVERY = 50       # kept samples between re-centrings of the completion mask (step one, tumbling)


def _finite_or_none(x: float) -> float | None:
    """For the saved metadata (JSON has no NaN/Infinity)."""
    return float(x) if math.isfinite(x) else None


class FieldCalibration:
    """One recalibration session (one magnetometer). Thread-safe for one feeder thread plus one thread
    running the fit (`pending_fit()` job) and any number of readers of `progress()`.

    Usage: `s = FieldCalibration(current_cal, config, reference)`, `s.start(now_t_s)`, then for every sample
    `s.add_sample(sample, FieldAttitude(...))`; if `auto_fit` is False, run `job = s.pending_fit()` off the event
    loop and hand its return value to `s.fit_done(value)`. `s.status`, `s.completion_pct`, `s.completion_mask`,
    `s.direction_hint()`, `s.result` and `s.pop_messages()` report.
    """

    def __init__(
        self,
        current: Calibration,
        config: FieldCalConfig | None = None,
        reference: "EarthField | None" = None,
        *,
        samples_are_calibrated: bool = True,
        fit_function: FitFunction | None = None,
        auto_fit: bool = True,
    ):
        self.current = current
        self.config = config or FieldCalConfig()
        self.reference = reference
        self.samples_are_calibrated = samples_are_calibrated
        self._fit_function = fit_function  # None: ahrsd.calibration.mag.fit.fit_mag (picklable jobs)
        self.auto_fit = auto_fit
        self._lock = threading.RLock()
        self._messages: list[tuple[int, str]] = []
        self.status = CalStatus.NOT_STARTED
        self.attempt = 0
        self.result: FieldCalResult | None = None
        self.fail_reason = ""
        cap = int(self.config.capacity)
        self._t = np.empty(cap)
        self._raw = np.empty((cap, 3))
        self._acc = np.empty((cap, 3))
        self._gyro = np.empty((cap, 3))
        self._rpy = np.empty((cap, 3))
        self._body_yaw = np.empty(cap)   # body yaw − sensor yaw (the mounting): course is the body's
        self._n = 0
        self._course = np.empty((int(self.config.course_capacity), 4))   # t_s, course_rad, speed, speed acc
        self._w_inv = np.linalg.inv(current.mag.soft_iron)
        self._reset_buffers()

    # ------------------------------------------------------------------ control
    def start(self, retry: bool | None = None, delay_s: float | None = None) -> None:
        with self._lock:
            if retry is not None or delay_s is not None:
                from dataclasses import replace

                self.config = replace(
                    self.config,
                    retry=self.config.retry if retry is None else bool(retry),
                    delay_s=self.config.delay_s if delay_s is None else max(0.0, float(delay_s)),
                )
            self.attempt = 1
            self._begin_attempt()

    def cancel(self) -> None:
        with self._lock:
            self.status = CalStatus.NOT_STARTED
            self.result = None
            self._reset_buffers()

    def tick(self, now_s: float) -> None:
        """Wall-clock check: FAILED when no sample arrived for `no_sample_timeout_s` while running."""
        with self._lock:
            if not self.status.running or self._last_sample_wall is None:
                if self.status.running and self._last_sample_wall is None:
                    self._last_sample_wall = now_s
                return
            if now_s - self._last_sample_wall > self.config.no_sample_timeout_s:
                self._fail(CalStatus.FAILED, f"no magnetometer samples for {self.config.no_sample_timeout_s:.0f} s", retry=False)

    def note_sample_wallclock(self, now_s: float) -> None:
        self._last_sample_wall = now_s

    # ------------------------------------------------------------------ feeding
    def add_sample(self, sample: "ImuSample", attitude: FieldAttitude | None = None,
                   now_s: float | None = None) -> None:
        """Feed one sample (calibrated with `current` if samples_are_calibrated, else raw) and the estimator's
        attitude for it in the sensor's axes (None: none yet). Cheap unless the sample is kept (store_rate_hz)."""
        if not self.status.running:
            return
        t = float(sample.t_s)
        if now_s is not None:
            self._last_sample_wall = now_s
        with self._lock:
            if not self._taking_samples_at(t):
                return
            mag = np.asarray(sample.mag_ut, dtype=np.float64)
            acc = np.asarray(sample.accel_m_s2, dtype=np.float64)
            gyro = np.asarray(sample.gyro_rad_s, dtype=np.float64)
            if not (np.all(np.isfinite(mag)) and np.all(np.isfinite(acc)) and np.all(np.isfinite(gyro))):
                self.rejected += 1
                return
            raw = self._w_inv @ mag + self.current.mag.hard_iron_ut if self.samples_are_calibrated else mag
            block = self._block_mean(t, raw, acc, gyro)
            if block is None:
                return
            t = float(block[0])
            dt_kept = t - self._t_last_kept
            self._t_last_kept = t
            raw, acc, gyro = block[1:4], block[4:7], block[7:10]
            roll, pitch, yaw, body_yaw_offset = self._kept_attitude(attitude, raw, acc, dt_kept)
            self._store(t, raw, acc, gyro, roll, pitch, yaw, body_yaw_offset)
            self._update_coverage(raw, roll, pitch, yaw)
            self._advance(t)

    def _taking_samples_at(self, t: float) -> bool:
        """Whether the session takes a sample at t: the run starts once the start delay is over (with its
        instruction to the person), no fit is running, and past timeout_s the session fails instead."""
        if self._t_start is None:
            self._t_start = t
        if self.status == CalStatus.WAITING_TO_START:
            if t - self._t_start < (self.config.delay_s if self.attempt == 1 else 0.0):
                return False
            self.status = CalStatus.RUNNING_STEP_ONE
            self._t_running = t
            self._say(6, "Mag cal: turn slowly through 360 deg" if self.config.vehicle_type != VehicleType.TUMBLE
                      else "Mag cal: rotate the vehicle through every orientation")
        if not self.status.running or self._fit_busy:
            return False
        if t - self._t_running > self.config.timeout_s:
            self._fail(CalStatus.FAILED, f"timed out at {self.completion_pct}%: {self._hint_text()}")
            return False
        return True

    def _block_mean(self, t: float, raw: np.ndarray, acc: np.ndarray, gyro: np.ndarray) -> np.ndarray | None:
        """Every sample between two kept ones is averaged into the kept one (a block mean, as the offline fit's
        block averaging does): the noise drops by √k and nothing is aliased. Bins of keep_period from the start
        of the run (aligned with the fit's own block averaging). Returns the finished block's mean
        [t, raw (3), acc (3), gyro (3)] when this sample opens the next bin, else None."""
        bin_index = math.floor((t - self._t_running) / self._keep_period)
        if self._block_n == 0 or bin_index == self._block_bin:
            self._block_bin = bin_index
            self._block_sum += np.concatenate(([t], raw, acc, gyro))
            self._block_n += 1
            return None
        block = self._block_sum / self._block_n
        self._block_sum = np.concatenate(([t], raw, acc, gyro))
        self._block_n = 1
        self._block_bin = bin_index
        return block

    def _kept_attitude(self, attitude: FieldAttitude | None, raw: np.ndarray, acc: np.ndarray,
                       dt_kept: float) -> tuple[float, float, float, float]:
        """(roll, pitch, yaw, body-yaw offset) of a kept sample: the estimator's, with the yaw integrated from its
        rate when it gives one; without an attitude, tilt from the accelerometer and heading from the field
        with the calibration in force."""
        if attitude is None:
            roll, pitch = (float(x) for x in roll_pitch_from_accel(acc))
            return roll, pitch, float(tilt_compensated_heading_rad(self.current.mag.apply(raw), roll, pitch)[0]), 0.0
        body_yaw_offset = 0.0
        roll, pitch = float(attitude.roll_rad), float(attitude.pitch_rad)
        yaw = float(attitude.yaw_rad)
        rate = attitude.rate_rad_s
        if rate is not None:
            # Heading coverage counts how far the vehicle has turned, from the gyro: the magnetic heading of an
            # uncalibrated compass need not go round once per turn (hard iron larger than the horizontal field).
            if self._turn_yaw is None or not math.isfinite(dt_kept) or dt_kept > 1.0:
                self._turn_yaw = yaw if self._turn_yaw is None else self._turn_yaw
            else:
                self._turn_yaw += yaw_rate_ned_rad_s(rate, roll, pitch) * dt_kept
            if attitude.body_yaw_rad is not None:
                body_yaw_offset = float(wrap_pi(float(attitude.body_yaw_rad) - float(attitude.yaw_rad)))
            yaw = self._turn_yaw
        return roll, pitch, yaw, body_yaw_offset

    def add_course(self, t_s: float, course_rad: float, ground_speed_m_s: float,
                   speed_acc_m_s: float = math.nan) -> bool:
        """One GNSS course over ground: t_s = the fix's time of validity on the samples' clock, course from
        true north (rad), ground speed (m/s), its 1σ accuracy (m/s, NaN unknown). Kept while the session
        collects; used for the constant heading offset. False (and counted) when rejected."""
        vals = (float(t_s), float(course_rad), float(ground_speed_m_s), float(speed_acc_m_s))
        with self._lock:
            if not self.status.running or self._fit_busy:
                return False
            if not all(math.isfinite(v) for v in vals[:3]) or vals[2] < 0:
                self.course_rejected += 1
                return False
            if self._n_course >= self._course.shape[0]:   # full: keep every other fix
                self._course[: self._n_course // 2] = self._course[: self._n_course: 2][: self._n_course // 2]
                self._n_course //= 2
            self._course[self._n_course] = vals
            self._n_course += 1
            return True

    def add_gnss_fix(self, fix: "GnssFix") -> bool:
        """A `GnssFix` (core/gnss.py): its horizontal velocity gives course and speed, `t_s` is its time of
        validity. Fixes without velocity are rejected (counted)."""
        if not fix.has_velocity:
            with self._lock:
                self.course_rejected += 1
            return False
        return self.add_course(fix.t_s, fix.course_rad, fix.ground_speed_m_s, fix.s_acc_m_s)

    def set_heading_offset(self, offset_deg: float, source: str, std_deg: float = math.nan) -> bool:
        """Rotate the finished (not yet saved) result's heading by `offset_deg` (a known heading, e.g.
        MAV_CMD_FIXED_MAG_CAL_YAW): the constant offset folded into the soft iron. False when there is no
        successful result."""
        with self._lock:
            if self.status != CalStatus.SUCCESS or self.result is None or not math.isfinite(offset_deg):
                return False
            res = self.result
            self.result = dataclasses.replace(res, model=fold_heading_offset(res.model, offset_deg),
                                              ardupilot=to_ardupilot(fold_heading_offset(res.model, offset_deg)),
                                              offset_std_deg=float(std_deg), offset_source=source,
                                              quality=dict(res.quality, known_heading_offset_deg=float(offset_deg)))
            return True

    # ------------------------------------------------------------------ fitting (off the event loop)
    def pending_fit(self) -> "FitJob | None":
        """A job to run (a picklable callable: in a worker thread or process) when the session waits for a
        fit, else None. Hand its return value to `fit_done`."""
        with self._lock:
            if not self._fit_request or self._fit_busy:
                return None
            self._fit_busy = True
            n = self._n
            return FitJob(
                stage=self._fit_request, config=self.config, reference=self.reference, current=self.current.mag,
                current_heading_std_deg=math.degrees(calibration_heading_sigma_rad(self.current)),
                t=self._t[:n].copy(), raw=self._raw[:n].copy(), acc=self._acc[:n].copy(),
                gyro=self._gyro[:n].copy(), rpy=self._rpy[:n].copy(), body_yaw=self._body_yaw[:n].copy(),
                course=self._course[: self._n_course].copy(),
                sphere_coverage=self.sphere_coverage, heading_coverage=self.heading_coverage,
                full_sphere=self._needs_sphere(), fit_function=self._fit_function,
            )

    def fit_done(self, outcome: Any) -> None:
        with self._lock:
            self._fit_busy = False
            self._fit_request = None
            if not self.status.running:
                return  # cancelled meanwhile
            stage, payload = outcome
            if stage == "preliminary":
                self._after_preliminary(payload)
            else:
                self._after_final(payload)

    # ------------------------------------------------------------------ reporting
    @property
    def completion_pct(self) -> int:
        with self._lock:
            if self.status == CalStatus.SUCCESS:
                return 100
            if self.status == CalStatus.RUNNING_STEP_ONE:
                return int(min(49.0, 50.0 * self._coverage_fraction(step_two=False)))
            if self.status == CalStatus.RUNNING_STEP_TWO:
                return int(min(99.0, 50.0 + 49.0 * self._coverage_fraction(step_two=True)))
            return 0

    @property
    def completion_mask(self) -> bytes:
        with self._lock:
            return completion_mask_bytes(np.flatnonzero(self._cells))

    @property
    def sphere_coverage(self) -> float:
        return float(np.count_nonzero(self._cells)) / N_SECTIONS

    @property
    def heading_coverage(self) -> float:
        return float(np.count_nonzero(self._sector_count >= self.config.samples_per_sector)) / self.config.heading_sectors

    def direction_hint(self) -> np.ndarray:
        """Body-frame unit vector for MAG_CAL_PROGRESS.direction: for a level vehicle, the horizontal
        direction of the nearest heading not yet covered (turn towards it: +y = turn right); for a tumbled
        vehicle, the body direction the (corrected) field should point along to fill the nearest empty cell."""
        with self._lock:
            if not self.status.running or self._n == 0:
                return np.zeros(3)
            if self._needs_sphere():
                empty = np.flatnonzero(~self._cells)
                if empty.size == 0:
                    return np.zeros(3)
                centres = section_centres()[empty]
                last = self._last_corrected / max(np.linalg.norm(self._last_corrected), 1e-9)
                return centres[int(np.argmax(centres @ last))]
            return self._level_turn_hint()

    def _level_turn_hint(self) -> np.ndarray:
        """A level vehicle: which way to turn, as the horizontal direction of the nearest heading sector still
        missing (in the step running), not counting the one the vehicle is in (it is filling that one: a 10° sector fills within a few
        kept samples, and pointing at it — almost straight ahead, |y| below a client's threshold — made the
        hint blink off at every sector). A gap the way the vehicle turns wins unless one behind is more than a
        sector nearer, so a steady turn keeps one hint; at least one sector off the bow, so it reads as a turn."""
        n = self.config.heading_sectors
        counts = self._sector_count_two if self.status == CalStatus.RUNNING_STEP_TWO else self._sector_count
        gaps = np.flatnonzero(counts < self.config.samples_per_sector)   # step two verifies on headings of its own
        if gaps.size == 0:
            return np.zeros(3)
        width = 2 * math.pi / n
        yaw = self._last_yaw
        others = gaps[gaps != int((yaw % (2 * math.pi)) / width) % n]
        if others.size == 0:
            return np.array([1.0, 0.0, 0.0])       # the last gap is the sector it is in: straight on
        diff = wrap_pi((others + 0.5) * width - yaw)
        d = float(diff[int(np.argmin(np.abs(diff)))])
        ahead = diff[np.sign(diff) == self._turn_sign] if self._turn_sign else diff[:0]
        if ahead.size and float(np.min(np.abs(ahead))) <= abs(d) + width:
            d = float(ahead[int(np.argmin(np.abs(ahead)))])
        d = math.copysign(max(abs(d), width), d)
        return np.array([math.cos(d), math.sin(d), 0.0])

    def pop_messages(self) -> list[tuple[int, str]]:
        """(MAV_SEVERITY, text) lines for a person, since the last call (not logged here: the caller logs them)."""
        with self._lock:
            out, self._messages = self._messages, []
            return out

    # ================================================================== internals
    def _reset_buffers(self) -> None:
        self._n = 0
        self._t_start: float | None = None
        self._t_running = 0.0
        self._t_last_kept = -math.inf
        self._keep_period = 1.0 / self.config.store_rate_hz
        self._cells = np.zeros(N_SECTIONS, dtype=bool)
        self._sector_count = np.zeros(self.config.heading_sectors, dtype=np.int64)
        self._sector_count_two = np.zeros(self.config.heading_sectors, dtype=np.int64)
        self._cells_two = np.zeros(N_SECTIONS, dtype=bool)
        self._tilt_max_deg = 0.0
        self._tilt_min_deg = 180.0
        self._prelim: MagModel = self.current.mag
        self._sphere_centre = np.zeros(3)   # step one, tumbled vehicle: centre of the running sphere fit
        self._fit_request: str | None = None
        self._fit_busy = False
        self._step_two_from = 0
        self._last_corrected = np.zeros(3)
        self._last_yaw = 0.0
        self._turn_sign = 0
        self._turn_yaw: float | None = None
        self._last_sample_wall: float | None = None
        self._last_hint_pct = -100
        self.rejected = 0
        self._block_sum = np.zeros(10)
        self._block_n = 0
        self._block_bin = 0
        self._n_course = 0
        self.course_rejected = 0

    def _begin_attempt(self) -> None:
        self._reset_buffers()
        self.result = None
        self.fail_reason = ""
        self.status = CalStatus.WAITING_TO_START
        if self.attempt > 1:
            self._say(5, f"Mag cal: attempt {self.attempt}")

    def _say(self, severity: int, text: str) -> None:
        # queued only: whoever runs the session says the line and logs it, once (daemon.magcal)
        self._messages.append((severity, text))

    def _store(self, t, raw, acc, gyro, roll, pitch, yaw, body_yaw_offset=0.0) -> None:
        if self._n >= self._t.shape[0]:  # full: keep every other sample, halve the keep rate
            keep = slice(0, self._n, 2)
            m = len(range(*keep.indices(self._n)))
            for arr in (self._t, self._raw, self._acc, self._gyro, self._rpy, self._body_yaw):
                arr[:m] = arr[keep]
            self._step_two_from = (self._step_two_from + 1) // 2
            self._n = m
            self._keep_period *= 2
        i = self._n
        self._t[i] = t
        self._raw[i] = raw
        self._acc[i] = acc
        self._gyro[i] = gyro
        self._rpy[i] = (roll, pitch, yaw)
        self._body_yaw[i] = body_yaw_offset
        self._n += 1

    def _update_coverage(self, raw, roll, pitch, yaw) -> None:
        if self.status == CalStatus.RUNNING_STEP_ONE and self._needs_sphere() and self._n % SPHERE_RECENTRE_EVERY == 0:
            self._recentre_sphere()
        corrected = self._prelim.apply(raw) - self._sphere_centre
        self._last_corrected = corrected
        # which way it turns (+1 right, -1 left, 0 below 1 °/s): the turn hint keeps to it
        step = float(wrap_pi(yaw - self._last_yaw)) if self._n > 1 else 0.0
        self._turn_sign = int(np.sign(step)) if abs(step) > math.radians(1.0) * self._keep_period else 0
        self._last_yaw = yaw
        s = geodesic_section(corrected)
        sector = int((yaw % (2 * math.pi)) / (2 * math.pi) * self.config.heading_sectors) % self.config.heading_sectors
        tilt = math.degrees(math.acos(max(-1.0, min(1.0, math.cos(roll) * math.cos(pitch)))))
        self._tilt_max_deg = max(self._tilt_max_deg, tilt)
        self._tilt_min_deg = min(self._tilt_min_deg, tilt)
        if self.status == CalStatus.RUNNING_STEP_TWO:
            self._sector_count_two[sector] += 1
            if s >= 0:
                self._cells_two[s] = True
        if s >= 0:
            self._cells[s] = True
        self._sector_count[sector] += 1

    def _recentre_sphere(self) -> None:
        """Step one on a tumbled vehicle: the completion mask counts field directions from the centre of the
        sphere the samples lie on (a running algebraic sphere fit), as CompassCalibrator's cells follow its
        running offsets; from the uncorrected origin, strong hard iron would keep half the cells out of reach."""
        corrected = self._prelim.apply(self._raw[: self._n])
        centre = algebraic_sphere_centre(corrected)
        if not np.all(np.isfinite(centre)):
            return
        self._sphere_centre = centre
        cells = geodesic_sections(corrected - centre)
        self._cells[:] = False
        self._cells[cells[cells >= 0]] = True

    def _needs_sphere(self) -> bool:
        vt = self.config.vehicle_type
        return vt == VehicleType.TUMBLE or (vt == VehicleType.AUTO and self._tilt_max_deg > self.config.tumble_tilt_deg)

    def _coverage_fraction(self, step_two: bool) -> float:
        cfg = self.config
        if self._needs_sphere():
            cells = self._cells_two if step_two else self._cells
            frac = np.count_nonzero(cells) / N_SECTIONS / cfg.sphere_target
        else:
            counts = self._sector_count_two if step_two else self._sector_count
            frac = np.count_nonzero(counts >= cfg.samples_per_sector) / cfg.heading_sectors
        if step_two:
            frac /= cfg.validation_fraction
        return float(min(1.0, frac))

    def _hint_text(self) -> str:
        if self._needs_sphere():
            return f"rotate through all orientations ({np.count_nonzero(self._cells)}/80 cells)"
        missing = int(np.count_nonzero(self._sector_count < self.config.samples_per_sector))
        return f"turn slowly through 360 deg ({missing * 360 // self.config.heading_sectors} deg of headings missing)"

    def _advance(self, t: float) -> None:
        pct = self.completion_pct
        if pct >= self._last_hint_pct + 25 and self.status == CalStatus.RUNNING_STEP_ONE and pct < 49:
            self._last_hint_pct = pct
            if pct > 0:
                self._say(6, f"Mag cal {pct}%: {self._hint_text()}")
        if self._fit_request:
            return
        if self.status == CalStatus.RUNNING_STEP_ONE and self._coverage_fraction(step_two=False) >= 1.0:
            self._request_fit("preliminary")
        elif self.status == CalStatus.RUNNING_STEP_TWO and self._coverage_fraction(step_two=True) >= 1.0:
            self._request_fit("final")

    def _request_fit(self, stage: str) -> None:
        self._fit_request = stage
        if self.auto_fit or stage == "preliminary":  # the preliminary fit is a small linear solve: inline
            job = self.pending_fit()
            if job is not None:
                self.fit_done(job())

    def _fail(self, status: CalStatus, reason: str, retry: bool | None = None) -> None:
        self.fail_reason = reason
        self._say(3, f"Mag cal failed: {reason}")
        if (self.config.retry if retry is None else retry) and status != CalStatus.NOT_STARTED:
            self.attempt += 1
            self._begin_attempt()
            return
        self.status = status
        self._fit_request = None

    # ------------------------------------------------------------------ fit outcomes (under the lock)
    def _after_preliminary(self, payload) -> None:
        if isinstance(payload, Exception):
            self._fail(CalStatus.FAILED, f"preliminary fit error: {payload}")
            return
        model, _quality = payload
        self._prelim = model
        self._sphere_centre = np.zeros(3)
        # re-mark the completion mask with the corrected field, as CompassCalibrator does after step one
        corrected = model.apply(self._raw[: self._n])
        cells = geodesic_sections(corrected)
        self._cells[:] = False
        self._cells[cells[cells >= 0]] = True
        self._step_two_from = self._n
        self.status = CalStatus.RUNNING_STEP_TWO
        self._say(6, "Mag cal: coverage complete, keep turning to verify")

    def _after_final(self, payload) -> None:
        if isinstance(payload, Exception):
            self._fail(CalStatus.FAILED, f"fit error: {payload}")
            return
        res: FieldCalResult = payload
        for note in res.reason.split("; ") if res.reason and res.status == CalStatus.SUCCESS else []:
            self._say(4, note)
        if res.status == CalStatus.SUCCESS:
            self.result = res
            self.status = CalStatus.SUCCESS
            self._say(5, f"Mag cal done: {res.method}, fitness {res.fitness_mgauss:.1f} mG. Accept to save")
            self._say(6, res.accuracy_text())
            if res.undetermined:
                self._say(4, "Mag cal: undetermined: " + ", ".join(res.undetermined))
        else:
            self.result = res
            self._fail(res.status, res.reason)


# ============================================================================ the fit (picklable, pure)


def shape_failure(ap: ArduPilotMagParams, offsets_max_mgauss: float) -> CalStatus | None:
    """ArduPilot's shape limits on a fitted model (CompassCalibrator::fit_acceptable; COMPASS_OFFS_MAX), the one
    rule both for choosing a full fit over the offsets and for judging the result: FAILED_OFFSETS when an offset
    reaches `offsets_max_mgauss`, FAILED_DIAG_SCALING when a diagonal or off-diagonal element is out of range,
    None within them."""
    if np.any(np.abs(ap.ofs_mgauss) >= offsets_max_mgauss):
        return CalStatus.FAILED_OFFSETS
    if np.any(ap.diag <= DIAG_MIN) or np.any(ap.diag >= DIAG_MAX) or np.any(np.abs(ap.offdiag) >= OFFDIAG_MAX):
        return CalStatus.FAILED_DIAG_SCALING
    return None


# why a full fit outside the shape limits was not taken (a note of the result: "backstepping rejected (…)")
_SHAPE_REFUSED = {CalStatus.FAILED_OFFSETS: "offsets too large",
                  CalStatus.FAILED_DIAG_SCALING: "diagonals out of range"}


@dataclass
class FitJob:
    """Everything a fit needs, copied out of the session so it can run in another thread or process
    (a process keeps a long fit from holding the daemon's GIL). Calling it returns (stage, payload)."""

    stage: str
    config: FieldCalConfig
    reference: "EarthField | None"
    current: MagModel
    t: np.ndarray
    raw: np.ndarray
    acc: np.ndarray
    gyro: np.ndarray
    rpy: np.ndarray
    sphere_coverage: float
    heading_coverage: float
    full_sphere: bool
    fit_function: FitFunction | None = None
    body_yaw: np.ndarray | None = None     # body yaw − sensor yaw per sample (rad)
    course: np.ndarray | None = None       # (k, 4): t_s, course_rad, ground speed m/s, speed accuracy m/s
    current_heading_std_deg: float = math.nan   # the calibration in force's predicted heading 1σ (NaN: unknown)

    def __call__(self):
        try:
            if self.stage == "preliminary":
                model, quality = fit_offsets_keep_soft_iron(
                    self.raw, self.current.soft_iron, self.current.hard_iron_ut, self.rpy[:, 0], self.rpy[:, 1],
                    self.reference)
                return self.stage, (model, quality)
            return self.stage, self._final_fit()
        except Exception as exc:  # a fit must never take the daemon down: report it as a failed calibration
            log.exception("magnetometer fit failed")
            return self.stage, exc

    def _final_fit(self) -> FieldCalResult:
        """The offsets with the soft iron in force, the full fit the data and the reference allow (chosen only if
        it is better), the heading offset from GNSS course, and the verdict."""
        rpy, raw = self.rpy, self.raw
        notes: list[str] = []
        quality = self._coverage_quality()
        offsets, q_off = fit_offsets_keep_soft_iron(
            raw, self.current.soft_iron, self.current.hard_iron_ut, rpy[:, 0], rpy[:, 1], self.reference)
        quality.update({f"offsets_{k}": v for k, v in q_off.items()})
        chosen = self._full_fit(offsets, quality, notes)
        if chosen is None:
            change = quality.get("full_vs_offsets", {}).get("offsets_heading_change_deg", math.nan)
            chosen = (offsets, "offsets", change, math.inf, ("soft iron (kept from the calibration in force)",))
        model, method, heading_std, offset_std, undetermined = chosen
        model, offset_std, offset_source = self._heading_offset(model, offset_std, notes, quality,
                                                                kept_soft_iron=method == "offsets")
        res = self._judge(model, method, quality, notes, partial=method == "offsets")
        # the full fit's levelling (the accelerometer here, as `calibrate mag` without --gnss) states its frame's
        # tilt and that tilt's share of heading_std (ins's frame-tilt states, estimator/mag_frame_tilt.py)
        levelling = (quality.get(f"{method}_predicted_heading") or {}).get("levelling")
        tilt_deg, tilt_heading_deg = frame_tilt_sigma_deg(levelling), frame_tilt_heading_std_deg(levelling)
        return dataclasses.replace(res, heading_std_deg=float(heading_std), offset_std_deg=float(offset_std),
                                   offset_source=offset_source, undetermined=tuple(undetermined),
                                   frame_tilt_std_deg=math.nan if tilt_deg is None else tilt_deg,
                                   frame_tilt_heading_std_deg=math.nan if tilt_heading_deg is None else tilt_heading_deg)

    def _coverage_quality(self) -> dict:
        """What the session's data covered: tilt range, sphere and heading coverage, samples and time span."""
        rpy = self.rpy
        tilt = np.degrees(np.arccos(np.clip(np.cos(rpy[:, 0]) * np.cos(rpy[:, 1]), -1, 1)))
        tilt_range = float(np.percentile(tilt, 98) - np.percentile(tilt, 2)) if len(tilt) else 0.0
        return {"tilt_range_deg": tilt_range, "sphere_coverage": self.sphere_coverage,
                "heading_coverage": self.heading_coverage, "n_samples": int(len(self.t)),
                "t_span_s": [float(self.t[0]), float(self.t[-1])] if len(self.t) else None}

    def _full_fit(self, offsets: MagModel, quality: dict, notes: list) -> tuple | None:
        """(model, method, heading std, offset std, undetermined) of the full fit when it is usable and better than
        `offsets`: the ellipsoid for a full sphere without a reference, else the back-stepping vertical channel
        against the WMM reference; None (with a note why) when only the offsets are."""
        fit = self.fit_function or fit_mag
        # the same data and the same call as `ahrsd calibrate mag --method backstepping`: roll/pitch from the
        # low-passed accelerometer with the centripetal lean fitted out (an estimator's roll/pitch lean into
        # turns and cannot be corrected after its filtering: docs/magcal-vehicle.md)
        data = MagFitInput(self.t, self.raw, self.acc, self.gyro)
        if self.full_sphere and self.reference is None:
            # without the WMM field the vertical channel has no reference: the attitude-independent ellipsoid
            fr = fit("ellipsoid", data, self.reference)
            if fr.refused is None and self._acceptable_shape(fr.model)[0]:
                self._add_quality(quality, "ellipsoid", fr.quality)
                return (fr.model, fr.method, math.nan, math.inf, ())
            notes.append(f"ellipsoid {fr.refused or 'rejected (' + self._acceptable_shape(fr.model)[1] + ')'}: "
                         "fitted offsets only")
            return None
        if self.reference is None:
            notes.append("no WMM reference: fitted offsets only")
            return None
        fr = fit("backstepping", data, self.reference)
        if fr.refused is not None:
            log.info("backstepping refused: %s", fr.refused)
            notes.append(f"full fit refused ({fr.refused}): fitted offsets only")
            return None
        ok, why = self._acceptable_shape(fr.model)
        self._add_quality(quality, "backstepping", fr.quality)
        if not ok:
            notes.append(f"backstepping rejected ({why}): fitted offsets only")
            return None
        cmp = compare_with_offsets(fr.model, offsets, fr.quality, self.reference.total_ut,
                                   self.reference.total_ut * math.sin(self.reference.inclination_rad))
        quality["full_vs_offsets"] = cmp
        if cmp["use_full"]:
            return (fr.model, fr.method, cmp["full_heading_std_deg"], cmp["full_offset_std_deg"],
                    tuple(fr.quality.get("undetermined") or ()))
        notes.append(f"full fit ({cmp['full_heading_std_deg']:.2f} deg 1-sigma) no better than "
                     f"the soft iron in force ({cmp['offsets_heading_change_deg']:.2f} deg apart): fitted offsets only")
        return None

    @staticmethod
    def _add_quality(quality: dict, method: str, fit_quality: dict | None) -> None:
        for k, v in (fit_quality or {}).items():
            if isinstance(v, (int, float, str, bool)):
                quality[f"{method}_{k}"] = v
        for k in ("predicted_heading", "parameter_std", "undetermined"):
            if fit_quality and k in fit_quality:
                quality[f"{method}_{k}"] = fit_quality[k]

    def _heading_offset(self, model: MagModel, offset_std: float, notes: list, quality: dict,
                        kept_soft_iron: bool = False):
        """The constant heading offset from GNSS course (course_offset.py), folded into the soft iron when it
        is better known than the field fit's own; else what the offset rests on."""
        cfg = self.config
        # a finite offset 1σ is the fit's own (propagated from its covariance through the tilt) and is stored and
        # used as such (calibration/heading_trust.py), however large; only an offset without any figure is
        # undetermined
        source = "tilt" if math.isfinite(offset_std) else "undetermined"
        if kept_soft_iron and math.isfinite(self.current_heading_std_deg):
            # an offsets-only refit keeps the soft iron in force, and with it the constant heading offset folded
            # into it (fold_heading_offset): the offset is the in-force calibration's, known as well as that
            # calibration said. Its whole predicted error is counted as this offset (its heading-dependent part
            # is refitted here), so the figure errs on the large side.
            offset_std, source = self.current_heading_std_deg, "calibration in force"
        if self.course is not None and len(self.course) and self.reference is not None:
            roll, pitch = self.rpy[:, 0], self.rpy[:, 1]
            psi = (np.radians(magnetic_heading_deg(model.apply(self.raw), roll, pitch))
                   + self.reference.declination_rad + (self.body_yaw if self.body_yaw is not None else 0.0))
            rate = np.array([yaw_rate_ned_rad_s(g, r, p) for g, r, p in zip(self.gyro, roll, pitch)])
            cf: CourseOffsetFit = fit_course_offset(
                self.course[:, 0], self.course[:, 1], self.course[:, 2], self.course[:, 3], self.t, psi, rate,
                min_speed_m_s=cfg.course_min_speed_m_s, max_turn_rate_deg_s=cfg.course_max_turn_rate_deg_s,
                window_s=cfg.course_window_s)
            quality["gnss_course"] = cf.to_dict()
            if cf.refused is not None:
                notes.append(f"GNSS course not used: {cf.refused}")
            elif cf.std_deg < offset_std:
                notes.extend(cf.notes)
                return fold_heading_offset(model, cf.offset_deg), cf.std_deg, "GNSS course"
        elif source == "undetermined" or offset_std > cfg.max_offset_std_deg:
            quality["gnss_course"] = {"refused": "no GNSS course received"}
        if source == "tilt" and offset_std > cfg.max_offset_std_deg:
            quality["offset_weakly_determined"] = True
        return model, offset_std, source

    def _acceptable_shape(self, model: MagModel) -> tuple[bool, str]:
        """Whether a full fit may replace the offsets: ArduPilot's shape limits (`shape_failure`), and why not."""
        failure = shape_failure(to_ardupilot(model), self.config.offsets_max_mgauss)
        return failure is None, _SHAPE_REFUSED.get(failure, "")

    def _judge(self, model: MagModel, method: str, quality, notes, partial: bool) -> FieldCalResult:
        cfg = self.config
        corrected = model.apply(self.raw)
        norms = np.linalg.norm(corrected, axis=1)
        radius_ut = float(self.reference.total_ut) if self.reference is not None else float(np.mean(norms))
        fitness = float(np.sqrt(np.mean((norms - radius_ut) ** 2))) * UT_TO_MGAUSS
        ap = to_ardupilot(model)
        status, reason = CalStatus.SUCCESS, "; ".join(notes)
        mean_radius_mg = float(np.mean(norms)) * UT_TO_MGAUSS
        shape = shape_failure(ap, cfg.offsets_max_mgauss)
        if not math.isfinite(fitness):
            status, reason = CalStatus.FAILED, "fit diverged (fitness NaN)"
        elif shape == CalStatus.FAILED_OFFSETS:
            status = CalStatus.FAILED_OFFSETS
            reason = f"offsets {np.round(ap.ofs_mgauss).astype(int).tolist()} > {cfg.offsets_max_mgauss:.0f} mG"
        elif shape == CalStatus.FAILED_DIAG_SCALING:
            status, reason = CalStatus.FAILED_DIAG_SCALING, "diagonals/off-diagonals out of range"
        elif not (RADIUS_MIN_MGAUSS < mean_radius_mg < RADIUS_MAX_MGAUSS):
            status, reason = CalStatus.BAD_RADIUS, f"radius {mean_radius_mg:.0f} mG outside [150, 950]"
        elif self.reference is not None and not (
            1 / MAX_SCALE_FACTOR <= self.reference.total_ut * UT_TO_MGAUSS / mean_radius_mg <= MAX_SCALE_FACTOR
        ):
            status = CalStatus.BAD_RADIUS
            reason = f"radius {mean_radius_mg:.0f} mG vs WMM {self.reference.total_ut * UT_TO_MGAUSS:.0f} mG"
        elif fitness > cfg.fitness_mgauss:
            status = CalStatus.FAILED_RESIDUALS_HIGH
            reason = f"fitness {fitness:.1f} > {cfg.fitness_mgauss:.1f} mG"
        quality = dict(quality, radius_mgauss=mean_radius_mg)
        return FieldCalResult(status, reason, method, model, self.current, fitness, quality, ap, partial)
