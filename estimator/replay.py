"""Run a stream of ImuSamples through an Estimator, one at a time as the daemon does, and tabulate the attitude.

The table has one row per input sample and the columns of ATTITUDE_COLUMNS (degrees for angles, rad/s for the
gyro bias, EstimateFlags as a number). The samples are used as given: a caller that wants them calibrated maps
them through its calibration first.

With GNSS fixes (an aided estimator: base.GnssAidedEstimator), the fixes are merged with the samples in time
order — each fix is offered before the first sample not earlier than its time of validity (fix_feed.py) — and
the table adds NAV_COLUMNS (the estimator's NavState; NaN while it has none). The fixes are used as given: a
caller validates them first (drivers.gnss.validation), as the daemon does.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator

import numpy as np

from ahrsd.core.angles import wrap_pi
from ahrsd.core.gnss import GnssFix
from ahrsd.core.sample import ImuSample

from .base import Estimator, FieldCircleCheckedEstimator, GnssAidedEstimator
from .calibration_heading import calibration_heading_variance_rad2
from .fix_feed import GnssFixFeed
from .rotations import quat_multiply

ATTITUDE_COLUMNS = (
    "t_s",                                     # the input sample's time, s
    "qw", "qx", "qy", "qz",                    # body (FRD) → NED, Hamilton, scalar first
    "roll_deg", "pitch_deg", "yaw_deg",        # ZYX Euler of that quaternion; yaw in [−180, 180)
    "heading_mag_deg", "heading_true_deg",     # [0, 360); true = magnetic + the estimator's declination
    "sigma_roll_deg", "sigma_pitch_deg", "sigma_yaw_deg",   # 1σ uncertainty
    "gyro_bias_x_rad_s", "gyro_bias_y_rad_s", "gyro_bias_z_rad_s",
    "flags",                                   # EstimateFlags as an integer
)
NAV_COLUMNS = (
    "vel_n_m_s", "vel_e_m_s", "vel_d_m_s",     # NED velocity of the IMU, m/s
    "lat_deg", "lon_deg", "alt_m",             # WGS-84 position of the IMU (alt above the ellipsoid)
)
HEADING_COLUMNS = (
    "gsf_yaw_deg", "gsf_sigma_deg",            # the magnetometer-free GNSS yaw (true north) and its 1σ; NaN: none yet
    "heading_state",                           # HeadingState as an integer (0 unknown, 1 magnetometer, 2 GNSS only, 3 learning)
)
FIELD_CIRCLE_COLUMNS = (
    "mag_cal_check",                           # field_circle.CalibrationVerdict: 0 not judged, 1 consistent, 2 wrong,
                                               # 3 corrected
    "mag_field_centre_ut",                     # |the levelled field circle's centre|, µT; NaN while not judged
)
CHUNK_ROWS = 16384   # rows per table yielded (memory stays constant for long recordings)
_DEG = 180.0 / math.pi


def replay_attitude(estimator: Estimator, samples: Iterable[ImuSample], true_north: bool = False,
                    chunk_rows: int = CHUNK_ROWS, fixes: Iterable[GnssFix] | None = None,
                    calibration_sigma_rad: float | None = None) -> Iterator[np.ndarray]:
    """Feed `samples` to `estimator.update` in order and yield the output as float64 tables of at most
    `chunk_rows` rows × len(ATTITUDE_COLUMNS) (+ len(NAV_COLUMNS) with `fixes`).

    true_north: rotate the quaternion and yaw about down by the estimator's declination (heading_true −
    heading_mag) so they are relative to true north; otherwise they stay relative to magnetic north, as
    estimated. Rows before the estimator initialised have NaN quaternion and angles.
    fixes: GNSS fixes in time order, for an aided estimator (base.GnssAidedEstimator), offered in time order
    with the samples; the table then ends with NAV_COLUMNS and HEADING_COLUMNS.
    calibration_sigma_rad: the heading error (1σ) the estimator was told the calibration leaves; with it, and an
    estimator that checks the calibration by the field's circle in turns (field_circle.py; `field_circle()` not
    None), the table ends with FIELD_CIRCLE_COLUMNS: the check's verdict against that figure per sample, as the
    daemon judges it (daemon/heading_status.py).
    """
    if fixes is not None and not isinstance(estimator, GnssAidedEstimator):
        raise ValueError(f"estimator {estimator.name!r} takes no GNSS fixes (not aided)")
    nan = math.nan
    deg = _DEG
    update = estimator.update
    rows: list[tuple] = []
    append = rows.append
    feed = GnssFixFeed(estimator, fixes) if fixes is not None else None
    no_nav = (nan,) * len(NAV_COLUMNS)
    no_gsf = (nan, nan)
    circle = checks_calibration(estimator, calibration_sigma_rad)
    claimed_var = calibration_heading_variance_rad2(calibration_sigma_rad) if circle is not None else nan
    result = verdict_cols = None
    for sample in samples:
        if feed is not None:
            feed.offer_until(sample.t_s)
        est = update(sample)
        if est.roll_rad == est.roll_rad:   # initialised (not NaN)
            q0, q1, q2, q3 = est.q_wxyz.tolist()
        else:
            q0 = q1 = q2 = q3 = nan
        s0, s1, s2 = est.sigma_rpy_rad.tolist()
        b0, b1, b2 = est.gyro_bias_rad_s.tolist()
        row = (sample.t_s, q0, q1, q2, q3, est.roll_rad * deg, est.pitch_rad * deg, est.yaw_rad * deg,
               est.heading_mag_rad * deg, est.heading_true_rad * deg, s0 * deg, s1 * deg, s2 * deg,
               b0, b1, b2, int(est.flags))
        if feed is not None:
            nav = est.nav
            row += no_nav if nav is None else (*nav.vel_ned_m_s.tolist(), nav.lat_deg, nav.lon_deg, nav.alt_m)
            hi = est.integrity
            row += (no_gsf if hi is None else (hi.gsf_yaw_rad * deg, hi.gsf_sigma_rad * deg)) + (int(est.heading_state),)
        if circle is not None:
            r = circle()
            if r is not result:      # a new result only once a second (field_circle.py solve_period_s)
                result = r
                v = r.verdict(claimed_var)
                verdict_cols = (int(v), r.offset_ut if v else nan)
            row += verdict_cols
        append(row)
        if len(rows) >= chunk_rows:
            yield _finish_table(rows, true_north)
            rows = []
            append = rows.append
    if rows:
        yield _finish_table(rows, true_north)


def checks_calibration(estimator: Estimator, calibration_sigma_rad: float | None):
    """The estimator's `field_circle` (its calibration check's latest result) when a calibration figure is given
    and the estimator runs the check, else None."""
    if calibration_sigma_rad is None or not isinstance(estimator, FieldCircleCheckedEstimator):
        return None
    return estimator.field_circle if estimator.field_circle() is not None else None


def _finish_table(rows: list[tuple], true_north: bool) -> np.ndarray:
    table = np.array(rows, dtype=np.float64).reshape(len(rows), -1)
    yaw = np.radians(table[:, 7])
    if true_north:
        n = len(table)
        decl = np.radians(table[:, 9] - table[:, 8])          # per row: the declination in force
        decl = np.where(np.isfinite(decl), decl, 0.0)
        # q_true = q_z(decl) ⊗ q_mag: the magnetic-north NED frame is the true one turned by decl about down
        rot_z = np.column_stack([np.cos(decl / 2), np.zeros(n), np.zeros(n), np.sin(decl / 2)])
        q = quat_multiply(rot_z, table[:, 1:5])
        table[:, 1:5] = q * np.where(q[:, :1] < 0, -1.0, 1.0)
        yaw = yaw + decl
    table[:, 7] = np.degrees(wrap_pi(yaw))                      # [−180, 180)
    return table
