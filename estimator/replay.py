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
from collections.abc import Callable, Iterable, Iterator

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
                    field_circle: FieldCircleColumns | None = None,
                    on_estimate: Callable[[object], None] | None = None) -> Iterator[np.ndarray]:
    """Feed `samples` to `estimator.update` in order and yield the output as float64 tables of at most
    `chunk_rows` rows × len(ATTITUDE_COLUMNS) (+ len(NAV_COLUMNS) with `fixes`).

    true_north: rotate the quaternion and yaw about down by the estimator's declination (heading_true −
    heading_mag) so they are relative to true north; otherwise they stay relative to magnetic north, as
    estimated. Rows before the estimator initialised have NaN quaternion and angles.
    fixes: GNSS fixes in time order, for an aided estimator (base.GnssAidedEstimator), offered in time order
    with the samples; the table then ends with NAV_COLUMNS and HEADING_COLUMNS.
    field_circle: this estimator's calibration check (`field_circle_columns`); with it the table ends with
    FIELD_CIRCLE_COLUMNS.
    on_estimate: called with each sample's estimate (e.g. a velocity_rejection_watch.RejectionWatch).
    """
    if fixes is not None and not isinstance(estimator, GnssAidedEstimator):
        raise ValueError(f"estimator {estimator.name!r} takes no GNSS fixes (not aided)")
    feed = GnssFixFeed(estimator, fixes) if fixes is not None else None
    for rows in _row_chunks(estimator, samples, feed, field_circle, chunk_rows, on_estimate):
        yield _finish_table(rows, true_north)


class FieldCircleColumns:
    """FIELD_CIRCLE_COLUMNS of each sample: the verdict of the estimator's calibration check by the field's circle
    in turns (field_circle.py) against the heading error (1σ) the estimator was told the calibration leaves, as
    the daemon judges it (daemon/heading_status.py)."""

    def __init__(self, field_circle, calibration_sigma_rad: float):
        self._field_circle = field_circle             # the estimator's latest check result (base.FieldCircleChecked…)
        self._claimed_var_rad2 = calibration_heading_variance_rad2(calibration_sigma_rad)
        self._result = None
        self._columns = None

    def columns(self) -> tuple[int, float]:
        """(the verdict as an integer, the circle centre's offset in µT, NaN while not judged)."""
        result = self._field_circle()
        if result is not self._result:      # a new result only once a second (field_circle.py solve_period_s)
            self._result = result
            verdict = result.verdict(self._claimed_var_rad2)
            self._columns = (int(verdict), result.offset_ut if verdict else math.nan)
        return self._columns


def field_circle_columns(estimator: Estimator, calibration_sigma_rad: float | None) -> FieldCircleColumns | None:
    """The estimator's calibration check for the replay table when a calibration figure is given and the
    estimator runs the check, else None."""
    if calibration_sigma_rad is None or not isinstance(estimator, FieldCircleCheckedEstimator):
        return None
    if estimator.field_circle() is None:
        return None
    return FieldCircleColumns(estimator.field_circle, calibration_sigma_rad)


def _row_chunks(estimator: Estimator, samples: Iterable[ImuSample], feed: GnssFixFeed | None,
                field_circle: FieldCircleColumns | None, chunk_rows: int,
                on_estimate: Callable[[object], None] | None = None) -> Iterator[list[tuple]]:
    """The table's rows, one per sample (the fixes due before it offered first, then its estimate), in lists of
    at most `chunk_rows` (memory stays constant for long recordings)."""
    update = estimator.update
    rows: list[tuple] = []
    for sample in samples:
        if feed is not None:
            feed.offer_until(sample.t_s)
        est = update(sample)
        if on_estimate is not None:
            on_estimate(est)
        row = _attitude_columns(sample.t_s, est)
        if feed is not None:
            row += _aided_columns(est)
        if field_circle is not None:
            row += field_circle.columns()
        rows.append(row)
        if len(rows) >= chunk_rows:
            yield rows
            rows = []
    if rows:
        yield rows


def _attitude_columns(t_s: float, est) -> tuple:
    """ATTITUDE_COLUMNS of one estimate (yaw still magnetic: _finish_table turns it)."""
    if est.roll_rad == est.roll_rad:   # initialised (not NaN)
        q0, q1, q2, q3 = est.q_wxyz.tolist()
    else:
        q0 = q1 = q2 = q3 = math.nan
    s0, s1, s2 = est.sigma_rpy_rad.tolist()
    b0, b1, b2 = est.gyro_bias_rad_s.tolist()
    return (t_s, q0, q1, q2, q3, est.roll_rad * _DEG, est.pitch_rad * _DEG, est.yaw_rad * _DEG,
            est.heading_mag_rad * _DEG, est.heading_true_rad * _DEG, s0 * _DEG, s1 * _DEG, s2 * _DEG,
            b0, b1, b2, int(est.flags))


_NO_NAV = (math.nan,) * len(NAV_COLUMNS)
_NO_GSF = (math.nan, math.nan)


def _aided_columns(est) -> tuple:
    """NAV_COLUMNS and HEADING_COLUMNS of one aided estimate (NaN where it has none yet)."""
    nav = est.nav
    row = _NO_NAV if nav is None else (*nav.vel_ned_m_s.tolist(), nav.lat_deg, nav.lon_deg, nav.alt_m)
    hi = est.integrity
    row += _NO_GSF if hi is None else (hi.gsf_yaw_rad * _DEG, hi.gsf_sigma_rad * _DEG)
    return row + (int(est.heading_state),)


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
