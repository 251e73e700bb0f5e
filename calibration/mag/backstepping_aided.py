"""Back-stepping levelled by the GNSS-aided estimator (`ahrsd calibrate mag --method backstepping --gnss`).

The vertical-channel fit (vertical_channel.py) takes the levelling as truth: a roll/pitch error δ is read as a
vertical-field error H·δ and the fit bends the soft iron to explain it, so the heading moves by about
tan(dip)·δ. With the true attitude the fit leaves hundredths of a degree of heading error on a heaving boat:
the error is the levelling's (measured in docs/magcal-vehicle.md). What this module does about it:

- **Smoothing** (`smooth`, on by default). The roll/pitch are those of the RTS smoother over the filter's whole
  run (estimator/ins_smoother.py): each sample levelled with every fix, before and after it, so the bias
  estimates of the end of the run reach back to its start. It removes most of the time-varying tilt error
  (docs/magcal-vehicle.md, "What the smoother removes"). A constant,
  body-fixed part remains: a tilt ε with the accelerometer bias g·e_z×ε and the gyro misalignments m_xz = ε_y,
  m_yz = −ε_x is (nearly) unobservable on a boat that mostly yaws, so what the heading acquisition and the
  sensor's own errors put there stays (measured in docs/magcal-vehicle.md).
- **The filter's start.** Until the aided filter has converged (the first 20–30 s) its tilt is off by tenths of
  a degree; `settled_tilt_sigma_deg` leaves out the samples whose filter tilt 1σ is above it (off by default:
  docs/magcal-vehicle.md has why).
- **The heading: the magnetometer, heading only.** Levelled without a heading, the filter has to take its yaw
  from the GNSS velocity during accelerations (Groves, Principles of GNSS, Inertial, and Multisensor Integrated
  Navigation Systems, 2nd ed., §14.2.1), and on a boat that turns steadily a yaw error looks like an
  accelerometer bias (the centripetal force, body-fixed in a steady turn, turned by the yaw error): on some runs
  it never acquires the yaw (it keeps rejecting and resetting the velocity, its tilt degrees off), on others it
  settles 10° off and the bias it draws to match tilts the horizon. So the run is levelled with the
  magnetometer in the filter, calibrated by the accelerometer-levelled fit (its heading within a degree or two),
  as a **heading-only** update (`mag_moves_tilt=False`): its calibration error must not move the tilt, which
  it would by tan(dip) times the heading error. The filter is told that calibration's stated heading 1σ
  (`heading_only_overrides`), as the daemon is told a saved one's: told nothing, `ins` takes the magnetometer for
  an uncalibrated one and holds its yaw from the GNSS velocity alone. Its heading checks are off: a rejection
  would hand the yaw to the GNSS velocity all the same. The fit from that levelling calibrates the
  magnetometer for the next pass (MAG_HEADING_PASSES). Only when the accelerometer-levelled fit is refused does
  the filter level without a magnetometer. `quality["aided_levelling"]["passes"]` reports each pass and its GNSS
  counters, and a warning says when a pass rejected the GNSS velocities, with the cause the evidence supports
  (levelling_rejections.py: the heading not yet found or just reset, or else the antenna's lever arm and the
  fixes' time stamps; the daemon's rule).
- **The accelerometer-levelled fit on a vehicle whose speed changes.** The accelerometer reads the vehicle's own
  acceleration as tilt; back-stepping fits out the lean of steady turns with one constant speed, which describes
  a boat but not a car that brakes, accelerates and corners at 0–20 m/s (its fit leaned tens of degrees or did
  not converge, and the magnetometer passes were lost). So that fit is made twice: as back-stepping makes it, and
  with the acceleration the GNSS speed and the gyro give removed from the accelerometer (gnss_motion.py); the one
  with the smaller vertical residual is kept (docs/gnss.md "Offline").
- **The accelerometer bias.** On a boat that stays near level and mostly yaws, a body-fixed accelerometer bias b
  and a tilt b/g give nearly the same GNSS velocities, so 180 s of motion splits them only weakly and the
  levelling's tilt is off by up to the bias the filter's prior allows (its default 10 mg: up to 0.6°). What
  splits them is a bench calibration: with the accelerometer calibrated (`ahrsd calibrate accel`, applied
  before the fit), pass `accel_bias_sigma_m_s2` = how well that calibration knows the bias
  (ACCEL_BIAS_SIGMA_CALIBRATED_M_S2 by default in the CLI), and the filter keeps the bias near zero and takes
  the tilt from the data (measured in docs/magcal-vehicle.md).

No centripetal compensation is applied: the aided horizon does not lean into turns.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ahrsd.estimator import AIDED_ESTIMATOR
from ahrsd.estimator.velocity_rejection_watch import RejectionWatch

from .levelling import attitude_from_estimator
from .levelling_rejections import MAX_REJECTED_VELOCITY_FRACTION, rejection_warning
from .levelling_error import body_fixed_tilt_sigma_rad
from .fit_types import MagFitInput, MagFitResult

SETTLED_TILT_SIGMA_DEG = math.inf   # fit only where the filter's tilt 1σ is below this; on the tuning seeds
                                    # (bench/backstepping_gnss.py --sweep) no limit did as well as any
MAG_HEADING_PASSES = 2          # aided levelling passes with the magnetometer (heading only), each calibrated by
                                # the previous fit; chosen on the tuning seeds (docs/magcal-vehicle.md)
MIN_SETTLED_FRACTION = 0.25    # fewer settled samples than this: fit them all (a short run)
SMOOTH_LEVELLING = True        # level with the RTS smoother over the whole run (estimator/ins_smoother.py)


def aided_roll_pitch(data: MagFitInput, fixes, declination_rad: float, mag_enabled: bool = False,
                     smooth: bool = SMOOTH_LEVELLING, accel_bias_sigma_m_s2: float | None = None,
                     filter_overrides: dict | None = None, watch=None):
    """The levelling the fit uses: roll, pitch and tilt 1σ (rad, per sample) of the aided estimator over `data`
    with the GNSS `fixes`, and the estimator (its GNSS counters). `smooth`: those of the RTS smoother over the
    filter's run (given every fix, before and after) instead of the filter's own (given the fixes before).
    `accel_bias_sigma_m_s2`: the filter's accelerometer-bias prior (None: its default, for an uncalibrated
    accelerometer). `filter_overrides`: other InsParams fields of the filter (e.g. the gyro-misalignment prior of
    a rate-table-calibrated gyro). `watch(est)`: made with the estimator before it runs, called with each
    sample's estimate (a `RejectionWatch`)."""
    from ahrsd.estimator import make_estimator
    from ahrsd.estimator.ins_smoother import SmoothingIns

    prior = dict(filter_overrides or {})
    if accel_bias_sigma_m_s2 is not None:
        prior["init_accel_bias_sigma_m_s2"] = float(accel_bias_sigma_m_s2)
    est = (SmoothingIns(declination_rad=declination_rad, mag_enabled=mag_enabled, **prior) if smooth else
           make_estimator(AIDED_ESTIMATOR, declination_rad=declination_rad, mag_enabled=mag_enabled, **prior))
    on_estimate = None if watch is None else watch(est)
    roll, pitch, tilt_sigma = attitude_from_estimator(data, AIDED_ESTIMATOR, fixes=fixes, estimator=est,
                                                      on_estimate=on_estimate)
    if smooth:
        sr, sp, ss = est.smoothed_roll_pitch()
        ok = np.isfinite(sr) & np.isfinite(sp)
        roll, pitch, tilt_sigma = np.where(ok, sr, roll), np.where(ok, sp, pitch), np.where(ok, ss, tilt_sigma)
    return roll, pitch, tilt_sigma, est


def _level(data: MagFitInput, fixes, declination_rad: float, mag_enabled: bool, settled_tilt_sigma_deg: float,
           smooth: bool, accel_bias_sigma_m_s2: float | None, filter_overrides: dict | None):
    """Roll, pitch, the settled mask, the levelling's body-fixed tilt 1σ per axis over the settled samples (rad)
    and whether the filter fused the GNSS velocity cleanly."""
    watches = []

    def watch(est):
        watches.append(RejectionWatch(est, mag_enabled))
        return watches[-1]

    roll, pitch, tilt_sigma, est = aided_roll_pitch(data, fixes, declination_rad, mag_enabled, smooth,
                                                    accel_bias_sigma_m_s2, filter_overrides, watch)
    settled = tilt_sigma <= math.radians(settled_tilt_sigma_deg)
    if settled.mean() < MIN_SETTLED_FRACTION:
        settled = np.ones(len(data), dtype=bool)
    c = est.gnss_counters
    healthy = c.reset_velocity == 0 and c.rejected_velocity <= MAX_REJECTED_VELOCITY_FRACTION * max(c.offered, 1)
    tilt_sigma_axis_rad = body_fixed_tilt_sigma_rad(tilt_sigma[settled])
    return roll, pitch, settled, tilt_sigma_axis_rad, {
        "gnss": {"offered": c.offered, "fused_velocity": c.fused_velocity, "rejected_velocity": c.rejected_velocity,
                 "reset_velocity": c.reset_velocity}, "rejected_velocity_by_cause": dict(watches[0].by_cause),
        "healthy": healthy,
        "tilt_sigma_per_axis_deg": math.degrees(tilt_sigma_axis_rad)}


def _fit_settled(data: MagFitInput, roll, pitch, settled, tilt_sigma_axis_rad: float, reference,
                 options: dict) -> MagFitResult:
    """The fit of the settled samples, levelled by `roll`/`pitch`, whose body-fixed tilt 1σ per axis enters
    its predicted heading error (levelling_error.py)."""
    from .backstepping import fit_backstepping

    return fit_backstepping(data.select(settled), reference, roll_rad=roll[settled], pitch_rad=pitch[settled],
                            speed_m_s=None, levelling_tilt_sigma_rad=tilt_sigma_axis_rad, **options)


def _pass_report(data: MagFitInput, settled, res: MagFitResult, health: dict) -> dict:
    return {"n_settled": int(settled.sum()), "settled_from_s": float(data.t_s[np.argmax(settled)]),
            "ok": res.ok, "refused": res.refused, **health}


def _vertical_rms_ut(res: MagFitResult) -> float:
    """The fit's vertical-channel residual RMS (µT): how well its levelling explains the vertical field."""
    vc = res.quality.get("vertical_channel") or {}
    value = vc.get("vertical_rms_ut")
    return float(value) if res.ok and value is not None else math.inf


def _accelerometer_levelled_fit(data: MagFitInput, fixes, reference, options: dict):
    """The fit that calibrates the magnetometer for the first heading-only pass, and its pass reports: levelled
    by the accelerometer as back-stepping does (a constant speed fitted to the turns' lean), and by the
    accelerometer less the vehicle's acceleration that the GNSS speed and the gyro give (gnss_motion.py); the one
    whose levelling explains the vertical field better (smaller vertical residual) is kept. A boat turns at a
    steady speed through the water and the first describes it better; a car's speed changes and only the second
    converges (docs/gnss.md "Offline")."""
    from .backstepping import fit_backstepping
    from .gnss_motion import accel_less_gnss_motion

    as_is = fit_backstepping(data, reference, **options)
    fits = [("accelerometer", as_is)]
    if data.accel_m_s2 is not None and data.gyro_rad_s is not None and sum(f.has_velocity for f in fixes) >= 2:
        less = dataclasses.replace(data, accel_m_s2=accel_less_gnss_motion(data.t_s, data.accel_m_s2,
                                                                           data.gyro_rad_s, fixes))
        fits.append(("accelerometer less the GNSS speed's acceleration",
                     fit_backstepping(less, reference, **{**options, "speed_m_s": None})))
    kept = min(range(len(fits)), key=lambda i: _vertical_rms_ut(fits[i][1]))
    passes = [{"levelling": name, "ok": res.ok, "refused": res.refused,
               "vertical_rms_ut": _vertical_rms_ut(res) if res.ok else None, "kept": i == kept}
              for i, (name, res) in enumerate(fits)]
    return fits[kept][1], passes


def stated_heading_sigma_rad(res: MagFitResult) -> float:
    """The heading 1σ (rad) a fit states for its calibration, as the daemon reads a saved one
    (calibration/heading_trust.py: √(heading-dependent² + offset²) of `predicted_heading`); NaN when it states none
    (the filter then treats the magnetometer as uncalibrated)."""
    pred = res.quality.get("predicted_heading") if res.ok else None
    if not isinstance(pred, dict):
        return math.nan
    sigma_deg = math.hypot(pred.get("heading_dependent_std_deg", math.nan), pred.get("offset_std_deg", math.nan))
    return math.radians(sigma_deg) if math.isfinite(sigma_deg) else math.nan


def heading_only_overrides(filter_overrides: dict | None, calibration_sigma_rad: float) -> dict:
    """The levelling filter of a magnetometer pass: the caller's overrides, the magnetometer a heading-only update
    whatever its trust (`mag_moves_tilt`, `mag_trusted_moves_tilt` off: the calibration being fitted must not move
    the tilt), and its calibration's stated heading 1σ (`mag_calibration_sigma_rad`, unless the caller sets one),
    so that the filter fuses it as the daemon fuses a saved calibration instead of taking it for an uncalibrated
    magnetometer (20°, its iron learned, its heading rejected when the GNSS-held heading disagrees) and holding
    its yaw from the GNSS velocity alone, which tilts the horizon: the GNSS acceleration is projected through
    that yaw (docs/magcal-vehicle.md, "What the held-out misses share").

    The heading checks are off (`heading_monitor`, unless the caller sets it): the magnetometer is always fused
    with that σ. The checks guard the daemon against a calibration that has gone wrong in operation; here the
    calibration was fitted to this very recording and states its error, and a rejection can only hand the yaw
    to the GNSS velocity, what the pass exists to avoid. Their gate now holds the magnetometer heading's share of
    the filter's unconverged tilt (tan(dip) times it), which rejected a good magnetometer in the first seconds at
    a high dip before; with the checks on, the passes measured the same as without them on the runs compared, so
    they stay off (docs/magcal-vehicle.md, "A magnetometer rejected at the start")."""
    overrides = {"mag_calibration_sigma_rad": calibration_sigma_rad, **(filter_overrides or {})}
    return {"heading_monitor": False, **overrides, "mag_moves_tilt": False, "mag_trusted_moves_tilt": False}


def fit_backstepping_aided(data: MagFitInput, fixes, reference, declination_rad: float,
                           settled_tilt_sigma_deg: float = SETTLED_TILT_SIGMA_DEG, smooth: bool = SMOOTH_LEVELLING,
                           accel_bias_sigma_m_s2: float | None = None, filter_overrides: dict | None = None,
                           **options) -> MagFitResult:
    """Back-stepping (`fit_backstepping`, `options` its BacksteppingOptions fields) levelled by the aided
    estimator over `data` (raw magnetometer; the accelerometer as calibrated, if it is) with the GNSS `fixes`
    (time of validity on the samples' time base). `accel_bias_sigma_m_s2`: how well the accelerometer bias is
    known (None: uncalibrated, the filter's default prior); `filter_overrides`: other InsParams fields of the
    levelling filter. See the module docstring;
    `quality["aided_levelling"]` reports each pass."""
    if accel_bias_sigma_m_s2 is not None and not (math.isfinite(accel_bias_sigma_m_s2) and accel_bias_sigma_m_s2 > 0):
        raise ValueError(f"accel_bias_sigma_m_s2 must be a positive number, got {accel_bias_sigma_m_s2!r}")
    seed, passes = _accelerometer_levelled_fit(data, fixes, reference, options)
    result, model = None, (seed.model if seed.ok else None)
    stated_sigma_rad = stated_heading_sigma_rad(seed)
    for _ in range(MAG_HEADING_PASSES if model is not None else 0):
        calibrated = dataclasses.replace(data, mag_ut=np.ascontiguousarray(model.apply(data.mag_ut)))
        roll, pitch, settled, tilt_sigma, health = _level(calibrated, fixes, declination_rad, True,
                                                          settled_tilt_sigma_deg, smooth, accel_bias_sigma_m_s2,
                                                          heading_only_overrides(filter_overrides, stated_sigma_rad))
        res = _fit_settled(data, roll, pitch, settled, tilt_sigma, reference, options)
        passes.append({"magnetometer": "heading only, the previous fit's calibration",
                       "calibration_sigma_deg": (math.degrees(stated_sigma_rad) if math.isfinite(stated_sigma_rad)
                                                 else None),
                       **_pass_report(data, settled, res, health)})
        if not res.ok:
            break
        result, model, levelling = res, res.model, (roll, pitch, settled)
        stated_sigma_rad = stated_heading_sigma_rad(res)
    if result is None:   # no calibration to take the heading from: the GNSS velocity alone
        roll, pitch, settled, tilt_sigma, health = _level(data, fixes, declination_rad, False,
                                                          settled_tilt_sigma_deg, smooth, accel_bias_sigma_m_s2,
                                                          filter_overrides)
        result = _fit_settled(data, roll, pitch, settled, tilt_sigma, reference, options)
        levelling = (roll, pitch, settled)
        passes.append({"magnetometer": "off", **_pass_report(data, settled, result, health)})
    warning = rejection_warning(passes, filter_overrides)
    if warning:
        result.quality.setdefault("warnings", []).append(warning)
    result.quality["aided_levelling"] = {"estimator": AIDED_ESTIMATOR, "smoothed": smooth,
                                         "accel_bias_sigma_m_s2": accel_bias_sigma_m_s2,
                                         "filter_overrides": dict(filter_overrides or {}),
                                         "settled_tilt_sigma_deg": settled_tilt_sigma_deg, "passes": passes}
    return dataclasses.replace(result, levelling=levelling)
