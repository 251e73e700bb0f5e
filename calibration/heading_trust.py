"""How far the aided estimator may trust a magnetometer calibration: its predicted heading error (1σ, rad), which
the daemon (at start and after every calibration change: `Ins.set_mag_calibration_sigma`) and `ahrsd replay
--calibration` pass to `ins` (InsParams.mag_calibration_sigma_rad).

Where the figure comes from, in order (the calibration's `metadata["mag"]`):
1. `heading_std_deg` and `offset_std_deg` — the field session's own prediction, propagated from its fit's
   parameter covariance (calibration/mag/vertical_channel.predicted_heading_std_deg): the heading-dependent
   part and the constant offset add in quadrature. An undetermined offset (no heading reference: stored as
   null) leaves the heading error unknown.
2. `residual_rms_ut` with the fit site (`site.lat_deg/lon_deg`, `ahrsd calibrate mag`): a field residual ε
   perpendicular to the horizontal field H turns the heading by ε/H, so ε/H (WMM's H at the site) is the
   figure. The residual of a fit understates what the fit cannot see (a constant offset), so it is a floor,
   not a bound; it is what the fit reports.
3. Nothing (identity calibration, fixed-yaw offsets only, older files): NaN — unknown: ins then trusts the
   magnetometer little, and without GNSS the heading is unknown (estimator/calibration_heading.py).
A magnetometer model that is the identity is a calibration like any other when it states its figure (a sensor
whose fit found nothing to correct).
"""

from __future__ import annotations

import math

from .models import MagModel

NAN = math.nan


def _finite(value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return NAN
    return v if math.isfinite(v) and v >= 0.0 else NAN


def calibration_heading_sigma_rad(calibration) -> float:
    """The predicted heading error (1σ, rad) of `calibration`'s magnetometer model, NaN when unknown."""
    if calibration is None:
        return NAN
    meta = calibration.metadata.get("mag") if isinstance(calibration.metadata, dict) else None
    if not isinstance(meta, dict):
        return NAN
    if "heading_std_deg" in meta:
        heading, offset = _finite(meta.get("heading_std_deg")), _finite(meta.get("offset_std_deg"))
        # the field session stores an undetermined offset (no heading reference) as None: the heading is unknown
        return math.radians(math.hypot(heading, offset)) if math.isfinite(heading + offset) else NAN
    residual = _finite(meta.get("residual_rms_ut"))
    site = meta.get("site")
    if math.isfinite(residual) and isinstance(site, dict):
        try:
            from ahrsd.core.wmm import earth_field

            h = earth_field(float(site["lat_deg"]), float(site["lon_deg"]), float(site.get("alt_m") or 0.0)).horizontal_ut
        except (KeyError, TypeError, ValueError):
            return NAN
        if h > 1.0:
            return math.atan2(residual, h)
    return NAN


def calibration_frame_tilt_sigma_rad(calibration) -> float:
    """The tilt of `calibration`'s magnetometer frame against the body, 1σ per axis, rad: the body-fixed tilt of
    the levelling that fitted it (`metadata["mag"]["frame_tilt_std_deg"]`, written by `ahrsd calibrate mag` from
    the fit's predicted heading: calibration/mag/levelling_error.frame_tilt_sigma_deg). 0 when the calibration
    states none (levelled with the true attitude, an offsets-only field session, older files): its frame is taken
    as the body's. ins carries the tilt as two states with this prior (estimator/mag_frame_tilt.py)."""
    return _stated_deg_as_rad(calibration, "frame_tilt_std_deg")


def calibration_frame_tilt_heading_sigma_rad(calibration) -> float:
    """The share of `calibration`'s stated heading error that its frame's tilt makes, 1σ rad (RMS over heading):
    tan(dip) times the frame tilt, which the fit's predicted heading error added in quadrature
    (`metadata["mag"]["frame_tilt_heading_std_deg"]`, written by `ahrsd calibrate mag` beside
    `frame_tilt_std_deg`). ins's frame-tilt states carry that share, so its harmonic states leave it out
    (mag_harmonics.prior_variances_rad2). 0 when not stated (a file written without the field): the harmonic
    states then keep the whole heading error."""
    return _stated_deg_as_rad(calibration, "frame_tilt_heading_std_deg")


def _stated_deg_as_rad(calibration, key: str) -> float:
    """`calibration`'s `metadata["mag"][key]` (deg, finite, ≥ 0) in rad; 0 when it is not stated."""
    if calibration is None:
        return 0.0
    meta = calibration.metadata.get("mag") if isinstance(calibration.metadata, dict) else None
    if not isinstance(meta, dict):
        return 0.0
    value = _finite(meta.get(key))
    return math.radians(value) if math.isfinite(value) else 0.0


def has_mag_calibration(calibration) -> bool:
    """Whether `calibration` holds a magnetometer calibration at all (a fitted or stated model), as opposed to
    none (no file, the identity, a gyro or accelerometer calibration alone). One that states no heading error
    (`calibration_heading_sigma_rad` NaN: an older file, fixed-yaw offsets only) is in force but of unknown
    quality: the daemon says so rather than "not calibrated"."""
    if calibration is None:
        return False
    meta = calibration.metadata.get("mag") if isinstance(calibration.metadata, dict) else None
    if isinstance(meta, dict):
        return True
    return calibration.mag != MagModel.identity()
