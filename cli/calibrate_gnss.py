"""`ahrsd calibrate mag --method backstepping --gnss GNSS.csv [--gnss-course]`: what a GNSS recording gives
back-stepping.

* Levelling: roll and pitch from the aided estimator (ins, its magnetometer a heading-only update calibrated
  by a first, accelerometer-levelled fit) run over the recording with the fixes and smoothed over the whole run
  (RTS, estimator/ins_smoother.py), instead of the accelerometer, whose apparent vertical leans in turns, waves
  and accelerations; no centripetal compensation is then needed (calibration.mag.backstepping_aided).
* The heading offset (--gnss-course): GNSS course over ground as the heading reference (the `heading_ref_deg`
  column's role), only on straight tracks above COURSE_MIN_SPEED_M_S (calibration.mag.swing.gnss_course_reference).
  Course is heading + crab (leeway, current, sideslip): a steady crab shifts the fitted offset by as much
  (measured in docs/gnss.md), hence opt-in: calibrate in still water / no crosswind, or give a heading_ref_deg
  column from a better reference instead.

The recording's t_s is the time of validity of each fix (docs/gnss.md), so the course needs no delay.
"""

from __future__ import annotations

import math

COURSE_MIN_SPEED_M_S = 2.0      # course 1σ ≈ speed accuracy / speed: 0.05/2 rad ≈ 1.4° (u-blox M8 sAcc)
COURSE_MAX_TURN_RATE_DEG_S = 1.0   # a straight track (calibration.mag.swing's default gate)


class GnssInputError(ValueError):
    """The GNSS recording cannot be used (unreadable, no usable fix): the message says why."""


def read_validated_fixes(path):
    """The recording's fixes that pass the validator, and the validator (for its counters)."""
    from ahrsd.drivers.gnss.recording import GnssRecordingFormatError, read_gnss_recording
    from ahrsd.drivers.gnss.validation import GnssFixValidator

    try:
        fixes = read_gnss_recording(path)
    except GnssRecordingFormatError as exc:
        raise GnssInputError(str(exc)) from None
    validator = GnssFixValidator(name=f"calibrate {path}")
    good = [f for f in fixes if validator.check(f) is None]
    if len(good) < 2:
        raise GnssInputError(f"{path}: {len(good)} usable fixes of {len(fixes)} ({validator.rejected} rejected)")
    return good, validator



def median_position(fixes) -> tuple[float, float, float]:
    """The median latitude, longitude (deg) and height (m) of `fixes` (validated; heights that are NaN left
    out, 0 when none has one): where the run was, for the reference field of a calibration made without
    --lat/--lon. Longitudes are taken relative to the first fix, so a run across ±180° has no false median."""
    import numpy as np

    lat = np.array([f.lat_deg for f in fixes], dtype=float)
    lon = np.array([f.lon_deg for f in fixes], dtype=float)
    alt = np.array([f.alt_m for f in fixes], dtype=float)
    lon_rel = (lon - lon[0] + 180.0) % 360.0 - 180.0
    lon_deg = (lon[0] + float(np.median(lon_rel)) + 180.0) % 360.0 - 180.0
    alt = alt[np.isfinite(alt)]
    return float(np.median(lat)), lon_deg, float(np.median(alt)) if alt.size else 0.0


def course_reference_deg(fixes, t_s):
    """GNSS course as a true-heading reference at the sample times `t_s` (NaN where slow or turning)."""
    import numpy as np

    from ahrsd.calibration.mag.swing import gnss_course_reference

    tf = np.array([f.t_s for f in fixes])
    course = np.array([math.degrees(f.course_rad) if f.has_velocity else np.nan for f in fixes])
    speed = np.array([f.ground_speed_m_s if f.has_velocity else np.nan for f in fixes])
    return gnss_course_reference(tf, course, speed, delay_s=0.0, min_speed_m_s=COURSE_MIN_SPEED_M_S,
                                 max_turn_rate_deg_s=COURSE_MAX_TURN_RATE_DEG_S, at_t_s=t_s)
