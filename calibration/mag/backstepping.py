"""Back-stepping magnetometer calibration for vehicles that cannot be tumbled: the `fit_mag("backstepping")`
entry point.

Two models, chosen by `BacksteppingOptions.model`:
- "general" (default): the vertical-channel least squares with a full soft-iron matrix
  (vertical_channel.py);
- "paper": the published algorithm as printed — Nourmohammadi & Sabet, "Back-stepping calibration algorithm
  for three-axial magnetometer applied to autonomous underwater vehicles with magnetic deviations", Journal
  of Control 16(3), 2022 — an axis-aligned sphere fit and a corrective loop on out-and-back legs
  (backstepping_paper.py).

`fit_backstepping` runs the same steps for both: usable samples, roll/pitch for levelling (low-passed
accelerometer or an estimator: levelling.py), block averaging to the fit rate (block_average.py), the
reference field, what the data support (observability.py), the fit, and — when the recording has a heading
reference — the deviation card with its constant offset folded into the soft iron (swing.py). A constant
heading offset (sensor yaw misalignment, coefficient A) is only weakly visible through tilt, hence the
reference. The report figure is `ahrsd.cli.plots.backstepping.plot_backstepping`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from ahrsd.core.angles import STANDARD_GRAVITY_M_S2, down_in_body, roll_pitch_from_accel, wrap_180_deg
from ahrsd.estimator.accel_bias_prior import ACCEL_BIAS_SIGMA_UNCALIBRATED_M_S2

from . import swing
from .backstepping_paper import (PAPER_STEP_TOL_UT, BacksteppingError, backstep_correct, inter_leg_step_ut,
                                 leg_statistics, magnetic_heading_deg, segment_legs, sphere_fit_paper)
from .block_average import block_average
from .levelling import roll_pitch_from_estimator
from .levelling_error import accel_bias_heading_std_deg, integrated_autocorrelation_time, tilt_heading_std_deg
from .fit_types import MagFitInput, MagFitResult, finite_rows, refuse
from ..models import MagModel
from .observability import assess_support, lowpass, parameter_uncertainty
from .vertical_channel import (ADIS16405_MAG_NOISE_UT, DEFAULT_TILT_SIGMA_DEG, centripetal_direction, corrected_down,
                               fit_vertical_channel, predicted_heading_std_deg)

METHOD = "backstepping"

# said in quality["attitude_source"] when the magnetometer and gyro were low-passed with the accelerometer before
# the fit (_levelling_attitude): the fit's blocks are then quieter than the unfiltered ones its residual is of
LOWPASSED_ALIKE = ", magnetometer and gyro alike"


def fit_blocks_lowpassed(quality: dict) -> bool:
    """Whether the blocks the vertical-channel fit saw were low-passed (its `vertical_channel.magnitude_rms_ut`
    and `vertical_rms_ut`), unlike the unfiltered 10 Hz block means of the result's `residual_rms_ut`."""
    return LOWPASSED_ALIKE in str(quality.get("attitude_source", ""))
DEFAULT_FIT_RATE_HZ = 10.0       # samples are block-averaged to this rate before fitting
MAX_PREDICTED_HEADING_STD_DEG = 3.0  # refuse when the data leave the heading worse than this (1σ)
MAX_FITTED_SPEED_M_S = 15.0      # a fitted centripetal speed above this is not a boat/AUV/rover calibration run
MAX_CENTRIPETAL_LEAN_RAD = 0.2   # …nor a lean into the turn of more than ~11°
DISTURBANCE_SIGMAS = 5.0         # |H| residual beyond this many robust σ: a magnetically disturbed sample
DISTURBED_FRACTION_FOR_ROBUST = 0.01
MAX_VEHICLE_TILT_DEG = 45.0      # 99th-percentile tilt above this: a hand tumble, not a vehicle (no speed model);
                                 # a small boat in a sea or an AUV rolls ±30° and more (tilt up to ~40°)


@dataclass(frozen=True)
class BacksteppingOptions:
    """Options of `fit_backstepping` (also accepted as keyword arguments of it and of `fit_mag`)."""

    model: str = "general"
    """"general" (full soft iron, vertical-channel least squares) or "paper" (the published algorithm:
    axis-aligned sphere fit + corrective loop on the legs)."""
    attitude: str = "auto"
    """Roll/pitch source: "auto"/"accel" (low-passed accelerometer; on a turning vehicle the centripetal lean
    is fitted out) or "mekf"/"estimator" (run `estimator` over the samples)."""
    roll_rad: Any = None
    """Roll per sample (rad); with `pitch_rad` it overrides `attitude`."""
    pitch_rad: Any = None
    """Pitch per sample (rad)."""
    rate_hz: float | None = DEFAULT_FIT_RATE_HZ
    """Block-average to this rate (Hz) before fitting; None: fit every sample."""
    accel_tau_s: float = 0.2
    """Time constant (s) of the zero-phase low-pass applied to the accelerometer before levelling."""
    field_ut: float | None = None
    """Total field intensity (µT); default: the WMM reference, else the mean raw magnitude."""
    inclination_deg: float | None = None
    """Dip (deg, down positive); default: the WMM reference's."""
    free_dip: bool | None = None
    """True: fit the dip as a free parameter even when the reference gives it."""
    legs: Any = None
    """Int label per sample of the out-and-back / multi-leg run (−1: not on a leg); default: detected from
    the calibrated heading (straight runs ≥ 60 s)."""
    calibration_mask: Any = None
    """("paper") bool per sample: the samples for the sphere fit (the paper's test 1); the rest is the leg
    run (test 2)."""
    heading_ref_delay_s: float = 0.0
    """Latency (s) of data.heading_ref_deg (GNSS course lags the vehicle; the paper assumed 2 s)."""
    fold_offset: bool = True
    """Fold the fitted constant heading offset A into the soft iron (a rotation about body z)."""
    sigma_mag_ut: float = ADIS16405_MAG_NOISE_UT
    """Magnetometer white noise per sample (µT, 1σ) before block averaging."""
    sigma_tilt_deg: float = DEFAULT_TILT_SIGMA_DEG
    """Roll/pitch error (deg, 1σ) of the levelling."""
    step_tol_ut: float = PAPER_STEP_TOL_UT
    """("paper") stop when the inter-leg step and the field error are within this (µT)."""
    max_passes: int = 10
    """("paper") most corrective passes."""
    max_heading_std_deg: float = MAX_PREDICTED_HEADING_STD_DEG
    """Refuse when the predicted heading-dependent 1σ (deg) exceeds this."""
    accel_bias_sigma_m_s2: float = ACCEL_BIAS_SIGMA_UNCALIBRATED_M_S2
    """The accelerometer's residual bias (1σ per axis, m/s²) when it levels the fit: its body-fixed tilt enters
    the predicted heading error (levelling_error.py). Not used with roll_rad/pitch_rad given."""
    levelling_tilt_sigma_rad: float | None = None
    """With roll_rad/pitch_rad given: the tilt error of that attitude that stays fixed in the body over the run
    (1σ per axis, rad; the GNSS-aided levelling's, backstepping_aided.py). It enters the predicted heading
    error as the accelerometer's bias does, tan(dip)·σ (levelling_error.py). None: the given attitude is taken
    as exact."""
    robust: Any = "auto"
    """"auto" (refit with a soft-L1 loss when more than 1 % of samples are magnetically disturbed), True or
    False."""
    estimator: str = "mekf"
    """Estimator name for attitude="mekf"/"estimator" (`ahrsd.estimator.make_estimator`)."""
    speed_m_s: Any = "auto"
    """Centripetal compensation of the levelling in turns (needs gyro samples): "auto" ("fit" when gyro
    samples exist and the run looks like a vehicle, else none), "fit" (a constant forward speed is fitted),
    a number or per-sample array (m/s, e.g. GNSS speed), or None (no compensation)."""

    def __post_init__(self):
        if self.model not in ("general", "paper"):
            raise ValueError(f"unknown backstepping model {self.model!r}; choose 'general' or 'paper'")
        if self.attitude not in ("auto", "accel", "mekf", "estimator"):
            raise ValueError(f"unknown attitude source {self.attitude!r}")


@dataclass
class _Usable:
    """The finite samples and the per-sample options cut to them."""

    data: MagFitInput
    keep: np.ndarray
    roll_rad: np.ndarray | None
    pitch_rad: np.ndarray | None
    legs: np.ndarray | None
    calibration_mask: np.ndarray | None
    unfiltered_mag_ut: np.ndarray | None = None   # before the levelling low-pass: for the reported residual


@dataclass
class _Blocks:
    """The samples averaged to the fit rate, with the levelling attitude and the heading reference."""

    t_s: np.ndarray
    mag_ut: np.ndarray
    down_body: np.ndarray
    roll_rad: np.ndarray
    pitch_rad: np.ndarray
    legs: np.ndarray | None
    calibration_mask: np.ndarray | None
    heading_ref_deg: np.ndarray | None
    gyro_rad_s: np.ndarray | None
    centripetal: tuple | None       # (gyro per block, speed per block or "fit"), None: no compensation
    sigma_mag_ut: float
    unfiltered_mag_ut: np.ndarray | None = None


@dataclass(frozen=True)
class _ReferenceField:
    total_ut: float
    vertical_ut: float | None       # None: the dip is fitted
    declination_deg: float


def fit_backstepping(data: MagFitInput, reference=None, options: BacksteppingOptions | None = None,
                     **overrides) -> MagFitResult:
    """Back-stepping / vertical-channel magnetometer calibration (the `fit_mag` "backstepping" method).

    reference: WMM `EarthField` at the site (total, vertical intensity, declination). Without it (and without
    field_ut/inclination_deg) the dip is fitted freely and the scale is the mean raw magnitude.
    options: a `BacksteppingOptions`; keyword arguments override its fields (unknown names: TypeError)."""
    t0 = time.perf_counter()
    opts = dataclasses.replace(options or BacksteppingOptions(), **overrides)
    usable = _usable_samples(data, opts)
    full = usable.data
    quality: dict = {"n_input": len(data), "n_dropped_nonfinite": int((~usable.keep).sum()), "model": opts.model}
    if len(full) < 10:
        return refuse(METHOD, f"only {len(full)} usable samples", **quality)
    levelled = _levelling_attitude(usable, opts, quality)
    if isinstance(levelled, MagFitResult):
        return levelled
    roll_rad, pitch_rad, vehicle_like = levelled
    blocks = _average_blocks(usable, opts, roll_rad, pitch_rad, vehicle_like, len(data), quality)
    if isinstance(blocks, MagFitResult):
        return blocks
    ref = _reference_field(blocks.mag_ut, reference, opts)
    quality["reference"] = {"total_ut": ref.total_ut, "total_source": _total_source(reference, opts),
                            "vertical_ut": ref.vertical_ut, "declination_deg": ref.declination_deg}
    support = _assess(blocks, ref, opts, quality)
    if support.refused:
        return refuse(METHOD, support.refused, **quality)
    levelling: dict = {}
    if opts.model == "paper":
        result = _fit_paper(blocks.t_s, blocks.mag_ut, blocks.roll_rad, blocks.pitch_rad, ref.total_ut,
                            ref.vertical_ut, blocks.legs, blocks.calibration_mask, quality, opts.step_tol_ut,
                            opts.max_passes)
    else:
        result = _fit_general(blocks.t_s, blocks.mag_ut, blocks.roll_rad, blocks.pitch_rad, ref.total_ut,
                              ref.vertical_ut, blocks.legs, quality, blocks.sigma_mag_ut, opts.sigma_tilt_deg,
                              opts.max_heading_std_deg, opts.robust, support, blocks.centripetal, levelling,
                              opts.accel_bias_sigma_m_s2, opts.levelling_tilt_sigma_rad)
    if isinstance(result, MagFitResult):
        return result
    mag_model = _with_heading_reference(result, blocks, ref, opts, levelling, quality)
    return _finish(mag_model, blocks, ref, quality, t0)


# ---------------------------------------------------------------------------------------------- the steps


def _usable_samples(data: MagFitInput, opts: BacksteppingOptions) -> _Usable:
    """Drop rows with a non-finite magnetometer (or accelerometer) reading, and cut the per-sample options."""
    keep = finite_rows(data.mag_ut)
    if data.accel_m_s2 is not None:
        keep &= np.all(np.isfinite(data.accel_m_s2), axis=1)
    full = data.select(keep) if (~keep).any() else data
    rp_given = opts.roll_rad is not None and opts.pitch_rad is not None
    return _Usable(
        full, keep,
        np.asarray(opts.roll_rad, dtype=np.float64)[keep] if rp_given else None,
        np.asarray(opts.pitch_rad, dtype=np.float64)[keep] if rp_given else None,
        None if opts.legs is None else np.asarray(opts.legs)[keep],
        None if opts.calibration_mask is None else np.asarray(opts.calibration_mask, dtype=bool)[keep],
    )


def _levelling_attitude(usable: _Usable, opts: BacksteppingOptions, quality: dict):
    """Roll and pitch per sample for levelling, and whether the run looks like a vehicle (tilt within
    MAX_VEHICLE_TILT_DEG); a refusal when there is nothing to level with.

    "auto" uses the low-passed accelerometer: the centripetal lean it shows in turns is fitted out later,
    while an estimator's roll/pitch lean the same way and cannot be compensated after its filtering (the
    measured comparison is in docs/magcal-vehicle.md). The estimator stays available as attitude="mekf"."""
    full = usable.data
    if usable.roll_rad is not None:
        quality["attitude_source"] = "given"
        return usable.roll_rad, usable.pitch_rad, True
    if full.accel_m_s2 is None:
        return refuse(METHOD, "back-stepping needs roll and pitch: the recording has no accelerometer "
                      "samples (or pass roll_rad/pitch_rad)", **quality)
    r0, p0 = roll_pitch_from_accel(full.accel_m_s2)
    tilt_deg = np.degrees(np.arccos(np.clip(np.cos(r0) * np.cos(p0), -1, 1)))
    vehicle_like = float(np.percentile(tilt_deg, 99)) <= MAX_VEHICLE_TILT_DEG
    if opts.attitude in ("mekf", "estimator"):
        if full.gyro_rad_s is None:
            return refuse(METHOD, "the estimator needs gyro samples for roll/pitch", **quality)
        try:
            roll_rad, pitch_rad = roll_pitch_from_estimator(full, opts.estimator)
        except BacksteppingError as exc:
            return refuse(METHOD, f"the estimator could not provide roll/pitch: {exc}", **quality)
        quality["attitude_source"] = f"estimator:{opts.estimator}"
        return roll_rad, pitch_rad, vehicle_like
    acc = lowpass(full.accel_m_s2, full.t_s, opts.accel_tau_s)
    roll_rad, pitch_rad = roll_pitch_from_accel(acc)
    # the same low-pass on the magnetometer and the gyro: the filter also attenuates the wave tilt the
    # accelerometer shows, and the vertical channel compares that tilt with the magnetometer's. Filtered on one
    # side only, a wave's tilt is shrunk on the accelerometer's side and the fit bends the soft iron to match
    # (how much: docs/magcal-vehicle.md). Only on a vehicle: in a hand tumble the field turns fast, and a
    # low-passed rotating vector is shorter than the field (the magnitude condition would be biased).
    quality["attitude_source"] = f"accelerometer (low-pass τ={opts.accel_tau_s:g} s)"
    if vehicle_like:
        usable.unfiltered_mag_ut = full.mag_ut
        usable.data = dataclasses.replace(full, mag_ut=lowpass(full.mag_ut, full.t_s, opts.accel_tau_s),
                                          gyro_rad_s=None if full.gyro_rad_s is None else
                                          lowpass(full.gyro_rad_s, full.t_s, opts.accel_tau_s))
        quality["attitude_source"] += LOWPASSED_ALIKE
    return roll_rad, pitch_rad, vehicle_like


def _delayed_heading_reference(full: MagFitInput, delay_s: float) -> np.ndarray | None:
    """data.heading_ref_deg moved earlier by its latency: interpolated only between two valid reference
    samples (never across a gap in the reference)."""
    href = full.heading_ref_deg
    if href is None or not delay_s:
        return href
    ok = np.isfinite(href)
    shifted = np.full_like(href, np.nan)
    if ok.sum() >= 2:
        unwrapped = np.degrees(np.unwrap(np.radians(href[ok])))
        tq = full.t_s + delay_s
        inside = (tq >= full.t_s[ok][0]) & (tq <= full.t_s[ok][-1])
        idx = np.clip(np.searchsorted(full.t_s, tq), 1, len(full) - 1)
        inside &= ok[idx] & ok[idx - 1]
        shifted[inside] = np.interp(tq[inside], full.t_s[ok], unwrapped) % 360.0
    return shifted


def _average_blocks(usable: _Usable, opts: BacksteppingOptions, roll_rad, pitch_rad, vehicle_like: bool,
                    n_input: int, quality: dict):
    """Average the samples in blocks of 1/rate_hz. Roll/pitch are averaged as the down vector (angles wrap at
    ±180° in a tumble); the heading reference over its valid samples only (a sparse GNSS reference, NaN
    between fixes, must not be lost because a block also holds NaN rows). The magnetometer noise of a block
    of k samples is σ/√k."""
    full = usable.data
    href = _delayed_heading_reference(full, opts.heading_ref_delay_s)
    leg_f = None if usable.legs is None else usable.legs.astype(np.float64)
    cal_f = None if usable.calibration_mask is None else usable.calibration_mask.astype(np.float64)
    speed_in, speed_arr = _forward_speed(usable, opts, vehicle_like, n_input)
    tb, cols, block_of = block_average(full.t_s, opts.rate_hz, full.mag_ut, down_in_body(roll_rad, pitch_rad),
                                       leg_f, cal_f, full.gyro_rad_s if speed_in is not None else None, speed_arr,
                                       usable.unfiltered_mag_ut)
    mag, down_b, legf, calf, gyro_b, speed_b, mag_unfiltered = cols
    heading_ref_b = None if href is None else _block_heading_deg(href, block_of, mag.shape[0])
    down_b = down_b / np.linalg.norm(down_b, axis=1, keepdims=True)
    roll = np.arctan2(down_b[:, 1], down_b[:, 2])
    pitch = -np.arcsin(np.clip(down_b[:, 0], -1.0, 1.0))
    if speed_in is not None and gyro_b is None:
        return refuse(METHOD, "centripetal compensation (speed_m_s) needs gyro samples; pass speed_m_s=None", **quality)
    centripetal = None if speed_in is None else (gyro_b, speed_b if speed_b is not None else speed_in)
    legs_b = None if legf is None else np.where(np.abs(legf - np.round(legf)) < 1e-9, np.round(legf), -1).astype(int)
    cal_b = None if calf is None else calf > 0.5
    quality["n_used"] = int(mag.shape[0])
    quality["fit_rate_hz"] = opts.rate_hz
    per_block = len(full) / max(mag.shape[0], 1)
    sigma_mag_ut = opts.sigma_mag_ut / math.sqrt(max(per_block, 1.0))
    quality["sigma_mag_fit_ut"] = sigma_mag_ut
    return _Blocks(tb, mag, down_b, roll, pitch, legs_b, cal_b, heading_ref_b, gyro_b, centripetal, sigma_mag_ut,
                   mag_unfiltered)


def _forward_speed(usable: _Usable, opts: BacksteppingOptions, vehicle_like: bool, n_input: int):
    """(the forward-speed option in force: None, "fit" or the speed given; the given speed per kept sample, m/s,
    or None). "auto" fits it for a vehicle with gyro samples: the model a = ω × [V, 0, 0] describes a vehicle,
    not a hand tumble."""
    speed_in = opts.speed_m_s
    if isinstance(speed_in, str) and speed_in == "auto":
        speed_in = "fit" if (usable.data.gyro_rad_s is not None and vehicle_like) else None
    speed_arr = None
    if speed_in is not None and not isinstance(speed_in, str):
        speed_arr = np.broadcast_to(np.asarray(speed_in, dtype=np.float64), (n_input,))[usable.keep].astype(np.float64)
    return speed_in, speed_arr


def _block_heading_deg(href_deg: np.ndarray, block_of: np.ndarray, n_blocks: int) -> np.ndarray:
    """The heading reference per block, [0, 360) deg: the circular mean of its valid (finite) samples; NaN where
    the block has none or they straddle a turn (mean resultant length ≤ 0.99)."""
    href_c, href_s = np.cos(np.radians(href_deg)), np.sin(np.radians(href_deg))
    valid = np.isfinite(href_c)
    count = np.bincount(block_of, weights=valid.astype(np.float64), minlength=n_blocks)
    with np.errstate(invalid="ignore", divide="ignore"):
        hc = np.bincount(block_of, weights=np.where(valid, href_c, 0.0), minlength=n_blocks) / count
        hs = np.bincount(block_of, weights=np.where(valid, href_s, 0.0), minlength=n_blocks) / count
    heading_ref_b = np.degrees(np.arctan2(hs, hc)) % 360.0
    with np.errstate(invalid="ignore"):
        heading_ref_b[~(np.hypot(hc, hs) > 0.99)] = np.nan    # no reference in the block, or it straddled a turn
    return heading_ref_b


def _total_source(reference, opts: BacksteppingOptions) -> str:
    if opts.field_ut is not None:
        return "given"
    if reference is not None:
        return "wmm"
    return "none: scale from the data (heading unaffected)"


def _reference_field(mag_ut: np.ndarray, reference, opts: BacksteppingOptions) -> _ReferenceField:
    """Total and vertical intensity (µT) the calibrated field must have, and the declination (deg)."""
    if opts.field_ut is not None:
        total = float(opts.field_ut)
    elif reference is not None:
        total = float(reference.total_ut)
    else:
        total = float(np.mean(np.linalg.norm(mag_ut - mag_ut.mean(axis=0), axis=1)))
    if opts.inclination_deg is not None:
        vertical = total * math.sin(math.radians(opts.inclination_deg))
    elif reference is not None:
        vertical = total * math.sin(reference.inclination_rad)
    else:
        vertical = None
    if opts.free_dip:
        vertical = None
    declination_deg = math.degrees(reference.declination_rad) if reference is not None else 0.0
    return _ReferenceField(total, vertical, declination_deg)


def _assess(blocks: _Blocks, ref: _ReferenceField, opts: BacksteppingOptions, quality: dict):
    """What the data support for the chosen model (coverage, tilt): observability.assess_support."""
    vertical = ref.vertical_ut
    support_model = "diagonal" if opts.model == "paper" else ("vertical" if vertical is not None else "vertical-free-dip")
    horizontal = math.sqrt(max(ref.total_ut**2 - vertical**2, 0.0)) if vertical is not None else None
    support = assess_support(blocks.mag_ut, None, support_model, roll_rad=blocks.roll_rad, pitch_rad=blocks.pitch_rad,
                             reference_known=vertical is not None, horizontal_ut=horizontal)
    quality.update(support.as_quality())
    return support


def _with_heading_reference(model: MagModel, blocks: _Blocks, ref: _ReferenceField, opts: BacksteppingOptions,
                            levelling: dict, quality: dict) -> MagModel:
    """With a heading reference: the deviation card, its constant offset folded into the soft iron. The
    heading comes from the same levelling the fit used: with the accelerometer's lean into turns left in, a
    vehicle turning one way shows a spurious semicircular term."""
    if blocks.heading_ref_deg is None or np.isfinite(blocks.heading_ref_deg).sum() < 1:
        return model
    roll_h, pitch_h = blocks.roll_rad, blocks.pitch_rad
    speed_used = levelling.get("speed_m_s")
    if speed_used is not None and not isinstance(speed_used, str) and blocks.gyro_rad_s is not None:
        d = corrected_down(blocks.down_body, centripetal_direction(blocks.gyro_rad_s, blocks.down_body), speed_used)
        roll_h, pitch_h = np.arctan2(d[:, 1], d[:, 2]), -np.arcsin(np.clip(d[:, 0], -1.0, 1.0))
    return _apply_heading_reference(model, blocks.mag_ut, roll_h, pitch_h, blocks.heading_ref_deg,
                                    ref.declination_deg, opts.fold_offset, quality)


def _finish(model: MagModel, blocks: _Blocks, ref: _ReferenceField, quality: dict, t0: float) -> MagFitResult:
    """The result, with the quality keys shared with the other magnetometer fits (`ahrsd calibrate mag`
    prints them)."""
    mag = blocks.unfiltered_mag_ut if blocks.unfiltered_mag_ut is not None else blocks.mag_ut
    res = np.linalg.norm(model.apply(mag), axis=1) - ref.total_ut
    quality["coverage"] = quality.get("sphere_coverage")
    quality["residual_max_ut"] = float(np.max(np.abs(res)))
    std = quality.get("parameter_std", {})
    if std:
        quality["sigma_hard_iron_ut"] = [std.get(f"hard_iron_{a}_ut", math.nan) for a in "xyz"]
    quality["time_s"] = time.perf_counter() - t0
    return MagFitResult(model, float(np.sqrt(np.mean(res**2))), METHOD, quality, None)


# ---------------------------------------------------------------------------------------------- the fits


def _fit_general(t_s, mag, roll, pitch, total, vertical, legs_b, quality, sigma_mag_ut, sigma_tilt_deg,
                 max_heading_std_deg, robust, support, centripetal=None, levelling=None,
                 accel_bias_sigma_m_s2=ACCEL_BIAS_SIGMA_UNCALIBRATED_M_S2, levelling_tilt_sigma_rad=None):
    """The generalised vertical-channel fit (vertical_channel.py) and its checks: the MagModel, or the refusal
    (a MagFitResult). What it found goes into `quality`; the forward speed the levelling was compensated with
    into `levelling`. The levelling's body-fixed tilt in the prediction: the accelerometer's bias
    (`accel_bias_sigma_m_s2`) when it levelled the fit, `levelling_tilt_sigma_rad` with the attitude given."""
    # the paper's sphere fit, for comparison (it often fails or is wrong on level data: that is the point)
    sph = sphere_fit_paper(mag, total)
    quality["sphere_fit_paper"] = ({"b_ut": sph.model.bias.tolist(), "s": sph.model.scale.tolist(),
                                    "condition_number": sph.condition_number} if sph.model is not None
                                   else {"refused": sph.reason, "condition_number": sph.condition_number})
    try:
        fit, cen = _vertical_channel_fit(mag, roll, pitch, total, vertical, quality, sigma_mag_ut, sigma_tilt_deg,
                                         robust, centripetal)
    except BacksteppingError as exc:
        return refuse(METHOD, str(exc), **quality)
    if levelling is not None:   # the forward speed the levelling was compensated with (None: not compensated)
        levelling["speed_m_s"] = (fit.speed_m_s if fit.speed_m_s is not None else
                                  (cen[1] if cen is not None else None))
    quality["vertical_channel"] = {
        "init": fit.init, "nfev": fit.nfev, "converged": fit.success, "message": fit.message,
        "magnitude_rms_ut": fit.magnitude_rms_ut, "vertical_rms_ut": fit.vertical_rms_ut,
        "whitened_rms": fit.whitened_rms, "vertical_ut": fit.vertical_ut, "free_dip": fit.free_dip,
        "centripetal_speed_m_s": (fit.speed_m_s if fit.speed_m_s is not None else
                                  ("given" if cen is not None else None)),
    }
    if fit.free_dip:
        quality["vertical_channel"]["dip_deg"] = math.degrees(math.asin(max(-1.0, min(1.0, fit.vertical_ut / total))))
    if quality.get("attitude_source") != "given":
        tilt = {"accel_bias_sigma_m_s2": accel_bias_sigma_m_s2}
    elif levelling_tilt_sigma_rad is not None:
        tilt = {"given_tilt_sigma_deg": math.degrees(levelling_tilt_sigma_rad),
                "tilt_sigma_rad": levelling_tilt_sigma_rad}
    else:
        tilt = None
    refused = _general_fit_refusal(fit, quality, support, max_heading_std_deg, tilt)
    if refused is not None:
        return refused
    model = MagModel(fit.hard_iron_ut, fit.soft_iron)
    _leg_report(t_s, model, mag, roll, pitch, legs_b, quality, sph.model.to_mag_model() if sph.model else None)
    return model


def _vertical_channel_fit(mag, roll, pitch, total, vertical, quality, sigma_mag_ut, sigma_tilt_deg, robust,
                          centripetal):
    """fit_vertical_channel, refitted without centripetal compensation when the fitted speed (or the lean it
    implies) is not plausible, and with a robust loss when magnetic disturbances show. Returns (the fit, the
    centripetal compensation it kept: (gyro, speed) or None); raises BacksteppingError."""
    cen = centripetal   # None once the fit runs without centripetal compensation
    fit = fit_vertical_channel(mag, roll, pitch, total, vertical, sigma_mag_ut=sigma_mag_ut,
                               sigma_tilt_rad=math.radians(sigma_tilt_deg), robust=robust is True,
                               gyro_rad_s=None if centripetal is None else centripetal[0],
                               speed_m_s=None if centripetal is None else centripetal[1])
    if fit.speed_m_s is not None:
        lean = np.max(np.abs(fit.speed_m_s * centripetal[0][:, 2])) / STANDARD_GRAVITY_M_S2
        if not (abs(fit.speed_m_s) <= MAX_FITTED_SPEED_M_S and lean <= MAX_CENTRIPETAL_LEAN_RAD):
            quality.setdefault("warnings", []).append(
                f"the fitted centripetal speed {fit.speed_m_s:.1f} m/s (lean up to {math.degrees(lean):.1f}°) is "
                "not plausible: refitted without centripetal compensation")
            cen = None
            fit = fit_vertical_channel(mag, roll, pitch, total, vertical, sigma_mag_ut=sigma_mag_ut,
                                       sigma_tilt_rad=math.radians(sigma_tilt_deg), robust=robust is True)
    # magnetic disturbances (a passing vehicle, a steel pier) show as magnitude outliers: count them and,
    # when more than 1 % of the samples are disturbed, refit with a robust (soft-L1) loss
    mres = np.linalg.norm((mag - fit.hard_iron_ut) @ fit.soft_iron.T, axis=1) - total
    scale = max(1.4826 * float(np.median(np.abs(mres - np.median(mres)))), sigma_mag_ut)
    disturbed = int(np.sum(np.abs(mres) > DISTURBANCE_SIGMAS * scale))
    quality["disturbed_samples"] = disturbed
    if robust == "auto" and disturbed > DISTURBED_FRACTION_FOR_ROBUST * mag.shape[0]:
        fit = fit_vertical_channel(mag, roll, pitch, total, vertical, sigma_mag_ut=sigma_mag_ut,
                                   sigma_tilt_rad=math.radians(sigma_tilt_deg), robust=True,
                                   gyro_rad_s=None if cen is None else cen[0],
                                   speed_m_s=None if cen is None else cen[1])
        quality.setdefault("warnings", []).append(
            f"{disturbed} of {mag.shape[0]} samples look magnetically disturbed (|H| off by more than "
            f"{DISTURBANCE_SIGMAS:g}σ): refitted with a robust loss")
    return fit, cen


def _general_fit_refusal(fit, quality, support, max_heading_std_deg, levelling_tilt=None):
    """The fit's parameter uncertainty and predicted heading error (into `quality`), and its refusal when the
    soft iron is a reflection, the fit did not converge, or the data leave the heading more uncertain than
    max_heading_std_deg; None when it is usable (with a warning when the constant offset is poorly known).
    levelling_tilt: the levelling's body-fixed tilt, {"accel_bias_sigma_m_s2": σ_b} for the accelerometer's
    bias or {"tilt_sigma_rad": 1σ per axis, "given_tilt_sigma_deg": the same} for a given attitude's (None: a
    given attitude taken as exact); it enters the prediction (`_with_levelling_error`)."""
    limits = {n: 0.02 for n in fit.names[:9]}
    limits.update({n: 1.0 for n in fit.names[9:12]})
    unc = parameter_uncertainty(fit.jacobian, fit.names, limits, residual_scale=max(fit.whitened_rms, 1.0))
    quality["condition_number"] = unc["condition_number"]
    quality["parameter_std"] = unc["std"]
    quality["undetermined"] = unc["undetermined"]
    envelope = max(10.0, support.tilt["tilt_max_deg"]) if support.tilt else 10.0
    # what the data determine decides the refusal (observability); the prediction reported adds the levelling
    pred = predicted_heading_std_deg(fit, envelope)
    quality["predicted_heading"] = _with_levelling_error(fit, envelope, levelling_tilt, pred)
    if np.linalg.det(fit.soft_iron) <= 0:
        return refuse(METHOD, "the fitted soft iron is a reflection (det ≤ 0): heading would be mirrored", **quality)
    if not fit.success and fit.whitened_rms > 10:
        return refuse(METHOD, f"the fit did not converge ({fit.message})", **quality)
    if pred["heading_dependent_std_deg"] > max_heading_std_deg:
        return refuse(METHOD, f"the data leave the heading uncertain by {pred['heading_dependent_std_deg']:.1f}° "
                      f"(1σ, within ±{envelope:.0f}° tilt; limit {max_heading_std_deg:.1f}°); parameters the data "
                      f"cannot determine: {', '.join(unc['undetermined']) or 'combinations of several'}", **quality)
    if pred["offset_std_deg"] > 0.5:
        quality.setdefault("warnings", []).append(
            f"the constant heading offset (yaw misalignment, coefficient A) is determined only to "
            f"{pred['offset_std_deg']:.1f}° (1σ); give a heading reference (GNSS course or known headings)")
    return None


def _with_levelling_error(fit, envelope_deg: float, levelling_tilt: dict | None, data_only: dict) -> dict:
    """The predicted heading error `data_only` (predicted_heading_std_deg), with the levelling's errors when
    they are known (`levelling_tilt`, _general_fit_refusal): the body-fixed tilt's heading-dependent error
    added in quadrature (levelling_error.py) and, levelled by the accelerometer, the covariance grown by the
    vertical residual's correlation time (the lean in turns and the waves the low-pass leaves). The aided
    levelling's varying error is not grown so: its residual is correlated over seconds (the smoother's slow
    drift), the offset is seen through the waves' tilt, which varies faster, and the growth overstated the offset
    tenfold (docs/magcal-vehicle.md, "The prediction with --gnss")."""
    if levelling_tilt is None or fit.vertical_residual is None:
        return data_only
    if "accel_bias_sigma_m_s2" not in levelling_tilt:      # an aided levelling's tilt (attitude given)
        tilt_deg = tilt_heading_std_deg(levelling_tilt["tilt_sigma_rad"], fit.vertical_ut, fit.total_ut)
        pred = dict(data_only, heading_dependent_std_deg=math.hypot(data_only["heading_dependent_std_deg"], tilt_deg))
        pred["levelling"] = {"given_tilt_sigma_deg": levelling_tilt["given_tilt_sigma_deg"],
                             "given_tilt_heading_std_deg": tilt_deg}
        return pred
    tau = integrated_autocorrelation_time(fit.vertical_residual)
    pred = predicted_heading_std_deg(fit, envelope_deg, covariance_inflation=tau)
    bias_deg = accel_bias_heading_std_deg(levelling_tilt["accel_bias_sigma_m_s2"], fit.vertical_ut, fit.total_ut)
    pred["heading_dependent_std_deg"] = math.hypot(pred["heading_dependent_std_deg"], bias_deg)
    pred["levelling"] = {"residual_correlation_samples": tau,
                         "accel_bias_sigma_m_s2": levelling_tilt["accel_bias_sigma_m_s2"],
                         "accel_bias_heading_std_deg": bias_deg}
    return pred


def _leg_report(t_s, model: MagModel, mag, roll, pitch, legs_b, quality, before: MagModel | None):
    cal = model.apply(mag)
    legs = legs_b
    if legs is None:
        legs = segment_legs(t_s, magnetic_heading_deg(cal, roll, pitch))
        quality_key = "legs_detected"
    else:
        quality_key = "legs_given"
    stats = leg_statistics(cal, roll, pitch, legs)
    if len(stats) < 2:
        return
    rep = {"source": quality_key, "legs": [s.__dict__ for s in stats], "step_after_ut": inter_leg_step_ut(stats)}
    if before is not None:
        rep["step_sphere_fit_ut"] = inter_leg_step_ut(leg_statistics(before.apply(mag), roll, pitch, legs))
    quality["out_and_back"] = rep


def _fit_paper(t_s, mag, roll, pitch, total, vertical, legs_b, cal_b, quality, step_tol_ut, max_passes):
    if vertical is None:
        return refuse(METHOD, "the paper's corrective steps need the reference horizontal and vertical "
                      "intensity (give the position for WMM)", **quality)
    sel = cal_b if cal_b is not None and cal_b.any() else np.ones(mag.shape[0], dtype=bool)
    sph = sphere_fit_paper(mag[sel], total)
    quality["sphere_fit_paper"] = {"condition_number": sph.condition_number, "n": int(sel.sum())}
    if sph.model is None:
        return refuse(METHOD, f"sphere fit (the paper's eqs. 12–17): {sph.reason}", **quality)
    quality["sphere_fit_paper"].update(b_ut=sph.model.bias.tolist(), s=sph.model.scale.tolist())
    hh_ref = math.sqrt(total**2 - vertical**2)
    legs = legs_b
    if legs is None or (legs >= 0).sum() == 0:
        rest = ~sel if (~sel).any() else sel
        cal = sph.model.apply(mag)
        legs = np.where(rest, segment_legs(t_s, magnetic_heading_deg(cal, roll, pitch)), -1)
        if (legs >= 0).sum() == 0:
            legs = np.where(rest, 0, -1)
    try:
        bs = backstep_correct(mag, roll, pitch, legs, sph.model, hh_ref, vertical, step_tol_ut=step_tol_ut,
                              field_tol_ut=step_tol_ut, max_passes=max_passes)
    except BacksteppingError as exc:
        return refuse(METHOD, str(exc), **quality)
    sz_ratio = bs.model.scale[2] / sph.model.scale[2]
    if not 0.5 < sz_ratio < 2.0:
        quality.setdefault("warnings", []).append(
            f"the loop changed s_z by a factor {sz_ratio:.2f}: the step is being absorbed by a non-physical "
            "vertical scale, typically horizontal→vertical coupling (off-diagonal soft iron) that the paper's "
            "diagonal model cannot represent; use the general model")
    quality["backstep"] = {"passes": [p.to_dict() for p in bs.passes], "converged": bs.converged,
                           "stop_reason": bs.stop_reason, "step_before_ut": bs.step_before_ut,
                           "step_after_ut": bs.step_after_ut, "n_legs": int(np.unique(legs[legs >= 0]).size)}
    return bs.model.to_mag_model()


def _apply_heading_reference(model: MagModel, mag, roll, pitch, heading_ref_true_deg, declination_deg,
                             fold_offset, quality) -> MagModel:
    ok = np.isfinite(heading_ref_true_deg)
    psi = magnetic_heading_deg(model.apply(mag[ok]), roll[ok], pitch[ok])
    ref_mag = (heading_ref_true_deg[ok] - declination_deg) % 360.0
    dev, card_report = swing.fit_deviation_card(psi, ref_mag, "reference headings")
    rep: dict = {"n": int(ok.sum()), **card_report}
    offset = dev.a_only_deg if "note" not in rep else dev.a_deg
    if fold_offset:
        model = fold_heading_offset(model, offset)
        rep["folded_offset_deg"] = offset
        psi2 = magnetic_heading_deg(model.apply(mag[ok]), roll[ok], pitch[ok])
        rep["rms_after_fold_deg"] = float(np.sqrt(np.mean(wrap_180_deg(ref_mag - psi2) ** 2)))
    quality["heading_reference"] = rep
    return model


def fold_heading_offset(model: MagModel, offset_deg: float) -> MagModel:
    """The model whose heading is `offset_deg` larger (the deviation coefficient A folded in): heading += A
    ⇔ the calibrated vector rotated by −A about body z, W ← Rz(−A)·W. Magnitude and vertical unchanged."""
    a = math.radians(offset_deg)
    rz = np.array([[math.cos(a), math.sin(a), 0.0], [-math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
    return MagModel(model.hard_iron_ut, rz @ model.soft_iron)
