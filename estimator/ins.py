"""`ins`: GNSS-aided attitude and navigation — a loosely coupled INS/GNSS error-state Kalman filter.

Groves, Principles of GNSS, Inertial, and Multisensor Integrated Navigation Systems, 2nd ed. (2013): §5.4 (NED
mechanisation with Earth rate, transport rate and normal gravity, `ins_mechanisation.py`) and ch. 14 (loose
coupling, the 15 error states — attitude, velocity, position, gyro bias, accelerometer
bias — plus the gyro's three scale factors and six misalignments, closed-loop feedback). GNSS velocity and position are fused at their time of validity against a short history of the
state (fixes arrive 50–200 ms late: the delayed-measurement idea of ArduPilot EKF3's fusion time horizon),
through the antenna lever arm, weighted by the accuracies the receiver reports, behind a χ² innovation gate.
The magnetometer corrects heading with mekf's disturbance rejection (`mag_heading.py`, the same code). Before
the first fix and after a long outage the accelerometer levels the attitude as in mekf (flagged); in a short
outage the filter dead-reckons.

The arithmetic is compiled with numba (`ins_core.py`). Parameters: `InsParams`; defaults `DEFAULT_INS_PARAMS`.
See docs/estimator.md ("The aided estimator: ins").
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass, replace

import numpy as np
from scipy.special import chdtri   # χ² inverse survival function (not scipy.stats: slow to import)

from ahrsd.core.estimate import AttitudeEstimate, EstimateFlags, HeadingState, NavState
from ahrsd.core.gnss import GnssFix
from ahrsd.core.sample import ImuSample

from . import ins_core as core
from . import mag_heading as mag
from .accel_axes_heading import accel_axes_heading_variance_rad2
from .accel_axes_tilt import ACCEL_MISALIGNMENT_SIGMA_RAD
from .base import DEFAULT_UNMODELLED_IRON_UT, LEARNED_WITH_GNSS
from .calibration_heading import calibration_heading_variance_rad2, calibration_states_error
from .gsf_yaw import GsfParams, gsf_reset, new_gsf_state
from .gnss_intake import GnssCounters, GnssFixIntake
from .heading_monitor import HeadingCheckRecord
from .heading_publication import HeadingReport
from .iron_in_use import IronInUse
from .ins_step_block import fast_step_block
from .ins_start import (axis_levelling_sigma_rad, carry_over_fix_delay, couple_yaw_to_tilt, first_fix_in_turn,
                        first_history_row, fresh_state, initial_covariance, initial_true_attitude, learned_to_keep,
                        levelling_force, levelling_lean, start_mag_reference, start_sensor_errors,
                        tilt_through_dip_row)
from .filter_output import (AttitudeFields, after_init_flags, attitude_estimate, estimate_flags,
                            float_field_slice, uninitialised_estimate)
from .kernel_entry import argument_types, entry_point
from .kernel_flags import IN_ACC_OK, IN_GYRO_OK, IN_MAG_OK, NEEDS_INIT, input_validity
from .lever_arm_consider import ARM_TERM_CORRELATION_S, arm_covariance_m2
from .heading_supervision import NAV_NO_GAIN_MASK, HeadingSupervision
from .ins_gnss_fusion import InsGnssFusion
from .yaw_reset import YawReset
from .lever_arm_fit import LeverArmFitResult
from .mag_heading import RELEARN_GATE_OPEN_S
from .mag_error_states import MagErrorStates
from .mag_heading_params import MagHeadingParams
from .constrained_update import scalar_update
from .params import with_overrides
from .estimate_view import BuiltEstimateView, EstimateView
from .field_circle import FieldCircleCheck, FieldCircleParams, FieldCircleResult
from .published_heading import FOLLOWING, PublishedHeading, published_offset_step, published_reset
from .slewed_yaw_kernel import slew_step
from .start_rerun import StartRecording, keep_iron, put_back_iron, start_heading
from .yaw_reset import restart_uncorrelated
from .rotations import quat_to_dcm
from .ins_published_terms import published_terms

log = logging.getLogger(__name__)
_DEG = math.pi / 180.0


@dataclass(frozen=True)
class InsParams(MagHeadingParams):
    """Tuning of the ins. SI units, angles in rad. Defaults for an ADIS16405-class IMU and a consumer GNSS
    receiver on a boat, car or aircraft."""

    # --- inertial sensors (process noise)
    gyro_noise_rad_s_sqrt_hz: float = 2.0 * _DEG / 60.0
    """Gyro angle random walk, rad/s/√Hz (ADIS16405 datasheet 2 °/√h)."""
    gyro_bias_walk_rad_s_sqrt_s: float = 2e-5
    """Gyro bias random walk, rad/s/√s: the ADIS16405 bias instability (0.007 °/s) over a 100 s correlation
    time, σ·√(2/τ)."""
    accel_noise_m_s2_sqrt_hz: float = 0.01
    """Accelerometer velocity random walk, m/s²/√Hz: three times the ADIS16405 datasheet's 0.2 m/s/√h, for the
    scale-factor and misalignment errors (0.3 %, 0.1°) the filter does not model."""
    accel_bias_walk_m_s2_sqrt_s: float = 3e-4
    """Accelerometer bias random walk, m/s²/√s (0.2 mg bias instability over 100 s)."""
    init_gyro_bias_sigma_rad_s: float = 0.5 * _DEG
    init_gyro_scale_sigma: float = 0.005
    """1σ of each gyro axis's scale-factor error at start-up (0.5 %; the simulated ADIS16405 has 0.3 %); 0
    removes the three scale states (the 15-state filter)."""
    gyro_scale_walk_sqrt_s: float = 1e-5
    """Random walk of the scale-factor errors, 1/√s."""
    init_gyro_misalignment_sigma_rad: float = 0.2 * _DEG
    """1σ of each off-diagonal element of the gyro's misalignment matrix at start-up (a gyro's axes lean by a
    tenth of a degree or so towards each other and towards the accelerometer's: the simulated ADIS16405 has
    0.1°); 0 removes the six misalignment states."""
    gyro_misalignment_walk_rad_sqrt_s: float = 1e-5
    """Random walk of the misalignment errors, rad/√s."""
    gyro_scale_clip: float = 0.05
    """Limit of each scale-factor and misalignment estimate (fraction, rad)."""
    init_accel_bias_sigma_m_s2: float = 0.1
    """1σ of the accelerometer bias at start-up, m/s² (10 mg)."""
    gyro_bias_clip_rad_s: float = 2.0 * _DEG
    accel_bias_clip_m_s2: float = 0.5
    cov_period_s: float = 0.01
    """The covariance is propagated (and the magnetometer and levelling updates run) every this long, with
    the summed increments of the samples in between, s. 0.01 s = every 8 samples at 819.2 SPS."""
    earth_rotation: bool = True
    """Earth rate, transport rate and Coriolis in the mechanisation (Groves 2nd ed. eqs. 2.123, 5.44, 5.54)."""
    earth_model: str = "wgs84"
    """Radii of curvature for position (Groves eq. 5.56) and transport rate (eq. 5.44): "wgs84" (the ellipsoid receivers
    report positions on) or "sphere" (R0 = 6 378 137 m, for tracks computed on that sphere)."""

    # --- GNSS
    lever_arm_m: tuple = (0.0, 0.0, 0.0)
    """Antenna position relative to the IMU in the body frame (FRD), m."""
    lever_arm_sigma_m: float = math.nan
    """1σ per axis of the antenna arm's error, m: the fusion adds what it makes of the fixes to their noise
    (lever_arm_consider.py): a told arm's few centimetres, or 2 m for an arm not told (left at (0, 0, 0)) on a
    vehicle whose antenna is within metres of the IMU. NaN (the default): the arm fused as exact."""
    lever_arm_adopt: bool = False
    """Fuse at the told arm plus the lever-arm check's fitted error once the fit is sure of it (lever_arm_fit.py),
    instead of publishing the heading unknown for as long as the told arm is found wrong. Off by default: a fit made
    while the heading is still unknown (an uncalibrated plane's first seconds) was found sure of arms of tens of
    metres and adopted them, bending the horizon by degrees (docs/gnss.md "The lever-arm check")."""
    min_h_acc_m: float = 0.3
    min_v_acc_m: float = 0.5
    min_s_acc_m_s: float = 0.03
    """Floors of the reported accuracies (receivers report optimistic figures in good conditions). A fix that
    reports none (NaN: NMEA) is weighted by ahrsd.core.gnss's DEFAULT_H_ACC_M, DEFAULT_V_ACC_M, DEFAULT_S_ACC_M_S,
    the defaults the recording reader fills in, so a live fix and its recording weigh the same."""
    use_vertical_velocity: bool = True
    """Fuse the vertical velocity when the fix has one (NaN in GPS_RAW_INT and NMEA)."""
    gate_false_alarm: float = 1e-5
    """Innovation gate: a fix is rejected when the χ² of its normalised innovation (velocity and position
    separately, 2 or 3 degrees of freedom) exceeds the (1 − this) quantile: 25.9 for 3 dof at 1e-5."""
    reject_reset_s: float = 5.0
    """A run of rejected velocities (positions) spanning this long resets the velocity (position) to the fix,
    without touching the attitude: a real, persistent change is re-acquired, s."""
    gnss_timeout_s: float = 2.5
    """No fix fused for this long: GNSS_OUTAGE (dead reckoning), s."""
    dead_reckon_s: float = 60.0
    """No fix fused for this long: the accelerometer levels the attitude again (unaided behaviour), s."""
    outage_reset_s: float = 5.0
    """The first fix after an outage longer than this sets velocity and position (attitude untouched): the
    dead-reckoned velocity error, fused, would move the tilt by tenths of a degree at once, s."""
    nav_drop_s: float = 120.0
    """No fix fused for this long: velocity and position are dropped (NavState None) until a fix sets them
    again, s."""
    nav_init_sigma_tilt_rad: float = 5.0 * _DEG
    """1σ tilt assumed when a fix first sets velocity and position (and after outage_reset_s): the levelled
    tilt leans into any sustained acceleration (a/g), which the GNSS velocity then corrects in seconds, rad."""
    max_delay_s: float = 1.0
    """Fixes whose time of validity is more than this behind the newest sample are not fused, s (the history
    holds 1024 samples: 1.25 s at 819.2 SPS)."""

    # --- accelerometer levelling (unaided: before the first fix and after dead_reckon_s)
    level_noise_m_s2: float = 0.15
    level_reject_m_s2: float = 2.0
    level_gate_rad: float = 15.0 * _DEG
    level_lowpass_tau_s: float = 1.5
    level_recover_s: float = 10.0
    """As mekf's acc_noise_m_s2, acc_reject_m_s2, acc_gate_rad, acc_lowpass_tau_s, acc_gate_recover_s."""
    turn_speed_m_s: float = 2.0
    """As mekf's: a plausible speed of the vehicle while it turns, m/s, for the published 1σ only while levelling
    (before the first fix and after dead_reckon_s without one; the estimate does not depend on it): a turn at ω
    about the vertical leans the levelled vertical by atan(ω·v/g), and through the dip the magnetometer heading
    by tan(I) times that (turn_lean.py). With GNSS the velocity observes the lean and the terms are off."""

    # --- magnetometer heading (mag_heading.py, mekf's check): as MekfParams
    mag_enabled: bool = True
    mag_moves_tilt: bool = False
    """While GNSS-aided, always let the magnetometer update move the tilt too (its row carries the tilt
    sensitivity either way, see ins_core._mag_update). False (default): only a trusted, consistent magnetometer
    may (`mag_trusted_moves_tilt`); a suspect one never moves the horizon."""
    mag_trusted_moves_tilt: bool = True
    """While the heading monitor finds the magnetometer consistent and its calibration trusted (heading state
    MAGNETOMETER, its heading 1σ below 3°), its update may correct the tilt too (at high dip a tilt error along
    magnetic north turns the magnetometer heading by tan(dip) times as much; the GNSS-held tilt alone leaves
    that in the heading). A magnetometer under suspicion — uncalibrated, learning, rejected, before the first
    check — never moves the horizon."""
    mag_calibration_sigma_rad: float = math.nan
    """1σ heading error the magnetometer calibration predicts (the daemon passes its calibration's figure). NaN:
    no calibration or its quality unknown — `mag_uncalibrated_sigma_rad`."""
    mag_uncalibrated_sigma_rad: float = 20.0 * _DEG
    """1σ heading error assumed of a magnetometer whose calibration is unknown (vehicle iron of tens of µT
    against a 20–30 µT horizontal field turns the heading by tens of degrees)."""
    mag_bias_tau_s: float = 1.0
    """Correlation time of the calibration's heading error, s: each update's noise is inflated by τ/Δt so that
    repeated updates do not average a bias away (ins_core._mag_update). With `mag_harmonic_states` only the part
    the harmonics leave (`mag_harmonic_residual_share`) is fused so."""
    mag_harmonic_states: bool = True
    """A calibration that states its heading error σ (and is trusted: at most the monitor's 3°) has that error
    carried as five filter states, the harmonics of the heading error in the magnetic heading (mag_harmonics.py),
    with σ² for their prior: while the vehicle holds a heading the error is a bias the filter cannot average away,
    as it turns the gyro separates the harmonics. False: the whole error is noise with `mag_bias_tau_s`."""
    mag_harmonic_offset_share: float = 0.25
    """The share of the calibration's heading variance given to the constant term c0 (the rest to the once- and
    twice-per-turn terms, mag_harmonics.prior_variances_rad2): chosen on in-sample seeds, checked held-out
    (docs/figures.md "A calibrated magnetometer's heading error as states")."""
    mag_wmm_declination_error: bool = True
    """True: a calibration's north-fixed heading offset state c0 (`mag_harmonic_states`) also carries WMM's own
    declination error at the filter's WMM field: its prior variance gains σ_D² (wmm_declination_error.py, WMM2025's
    error model), added once the field is known. The true field differs from WMM's by that much, fixed to north;
    with it the calibrated boat stays within 3σ under a field half a µT off WMM's. On since the start's yaw is
    coupled to its tilt at the first fix (Ins._couple_start_yaw_to_tilt): before, c0 took up the start's
    over-confident yaw error in tests/test_ins.py's NEES (docs/gnss.md, "the start's yaw coupled to its tilt").
    False: the calibration's own figure alone."""
    mag_harmonic_residual_share: float = 0.1
    """The share of the calibration's heading variance the harmonics do not hold (a boat's heel and a plane's
    bank turn the field against the calibration's levelled one: error that changes in seconds), fused as noise
    lasting `mag_bias_tau_s`."""
    mag_harmonic_walk_rad_sqrt_s: float = 1e-5
    """Random walk of the harmonic coefficients, rad/√s: a calibration's error drifts with temperature and load
    only slowly (0.03° in an hour)."""
    mag_calibration_frame_tilt_sigma_rad: float = 0.0
    """1σ per axis of the tilt of the magnetometer calibration's frame against the body: its levelling's
    body-fixed tilt, as the calibration states it (calibration/heading_trust.calibration_frame_tilt_sigma_rad; the
    daemon and `ahrsd replay --calibration` pass it). With the harmonic states on, a calibration that states one has
    the tilt carried as two filter states, ε about body x and y, with this prior (mag_frame_tilt.py); 0: the
    calibration's frame is the body's (levelled with the true attitude), the states stay off."""
    mag_calibration_frame_tilt_heading_sigma_rad: float = 0.0
    """The share of the calibration's heading error (`mag_calibration_sigma_rad`) its frame's tilt makes, 1σ rad
    (tan(dip) times the tilt, which the calibration's prediction added in quadrature: heading_trust.py). While the
    frame-tilt states carry the tilt, the calibration's harmonic states leave this share out of their once-per-turn
    prior (mag_harmonics.prior_variances_rad2), or the heading σ would count it twice. 0: not stated (older
    files), the harmonics keep the whole error."""
    mag_frame_tilt_shares_accel_bias: bool = True
    """The frame tilt's prior is correlated with the filter's accelerometer-bias error (mag_frame_tilt.accel_bias_share):
    the calibration's levelling could not tell the same bias from tilt. False: independent of every other state."""
    gnss_yaw: bool = True
    """Run the magnetometer-free Gaussian-sum GNSS yaw (gsf_yaw.py) beside the filter: the heading monitor checks
    the magnetometer against it and resets the yaw to it."""
    mag_uncalibrated_tau_s: float = 10.0
    """... of a magnetometer whose calibration is unknown and nothing learned yet, s (the iron's heading error
    changes only as the vehicle turns)."""
    heading_monitor: bool = True
    """Check the magnetometer against the filter's heading innovations and the GNSS yaw, reject it when they
    disagree, reset the yaw to the GNSS yaw, learn the iron (heading_monitor.py). False: the magnetometer is
    always fused with its calibration's noise."""
    iron_learning: bool = True
    """Learn the hard and soft iron left after the calibration while the GNSS holds the heading (IronLearner)."""
    iron_prior_sigma_ut: float = 10.0
    """1σ prior of each axis of the learned hard iron, µT."""
    iron_soft_prior_sigma: float = 0.1
    """1σ prior of each element of the learned soft iron D (m = (I + D)·B + b), dimensionless: vehicle iron
    scales and couples the field by up to ~10 % (simulation/magnetic.py VehicleIron). 0: learn the hard iron
    alone."""
    iron_unmodelled_ut: float = DEFAULT_UNMODELLED_IRON_UT
    """1σ per axis of the field error the learned hard and soft iron do not explain (WMM and local anomalies,
    the soft iron's third column while the vehicle stays level), µT: both the learner's measurement noise and,
    as heading, the floor of the learned magnetometer's error. Learning the hard iron alone needed 2.5 µT (the
    unlearned soft iron of a strong vehicle iron is a few µT)."""
    iron_learned_tau_s: float = 3.0
    """Correlation time of the heading error the learned iron leaves, s (the magnetometer update's noise is
    inflated by τ/Δt, ins_core._mag_update)."""
    iron_heading_corr_rad: float = 0.5
    """While the heading monitor rejects a magnetometer without a trusted calibration, all the iron was learned
    since (against the GNSS heading; nothing learned or restored before the rejection, which that iron may have
    caused), and its floor plus the filter's yaw variance keeps it above the trust limit
    (`magnetometer_use.never_trusted_here`: the floor alone where H is below ~19 µT; with the yaw's just above, as at
    Punta Arenas, docs/gnss.md "boat39"), its heading is still fused at the learned iron's honest slowly varying variance
    (`_magnetometer_trust_var`: the worst level heading plus the floor), never moving the tilt: too wide to set the
    heading, it still adds to the GNSS. The error a learned iron leaves is a function of the heading (the hard
    iron's once per turn, the soft iron's twice), constant while the heading holds: its correlation is taken as
    lasting this change of heading, so its correlation time is this over the vertical rate (at least
    `iron_learned_tau_s`), rad. 0: a rejected magnetometer is not fused."""
    iron_harmonic_states: bool = True
    """Once the iron learning has ended (a learned or restored iron, the magnetometer used and not being learned,
    the filter GNSS-aided), the heading error that iron leaves is carried as the five harmonic states
    (mag_harmonics.py, with `mag_harmonic_states`), their prior the learner's covariance projected on them
    (correlated, `mag_harmonics.prior_from_heading_rows`) at the WMM field: the error is a function of the
    heading, constant while the heading holds, which only turns and the GNSS can learn. Fused as noise lasting
    `iron_learned_tau_s`, a straight leg averaged it away and pulled the heading (and the vertical gyro bias) to
    the learned magnetometer's (docs/gnss.md "A learned iron's error as states"). False: that noise."""
    iron_harmonic_residual_share: float = 0.0
    """With `iron_harmonic_states`: the share of the learned magnetometer's floor (mag_error_states.learned_floor_var_rad2, what no
    learned iron explains) still fused as noise lasting `iron_learned_tau_s`; the rest is added to the states'
    prior, split as a calibration's (`mag_harmonic_offset_share`). 0: all of it is a state. What the floor stands
    for (`iron_unmodelled_ut`) is a field error fixed in the NED frame (the WMM's error, a local anomaly: a heading
    offset, c0) or fixed to the body (the soft iron's third column times the vertical field while the vehicle stays
    level: once per turn, c1 / s1): a function of the heading, which a straight leg does not average away. Fused as
    noise renewed every `iron_learned_tau_s`, a wide floor (a weak horizontal field) kept a trusted learned
    magnetometer from holding a GNSS–inertial yaw that had drifted, though the magnetometer itself was right
    (docs/gnss.md "(highlat)")."""
    iron_tau_s: float = 5.0
    """Correlation time of that unexplained error while the vehicle moves, s (the learner's noise is inflated
    by τ/Δt between fixes)."""
    heading_observable_sigma_rad: float = 2.0 * _DEG
    """The GNSS holds the heading (iron learned, magnetometer allowed back) while the yaw 1σ is below this: the
    filter's own and, without a trusted calibration until a GNSS yaw confirms the heading, the floor published for it
    (HeadingConfirmation.unconfirmed_yaw_sigma)."""
    heading_unknown_sigma_rad: float = 15.0 * _DEG
    """Above this yaw 1σ the heading state is UNKNOWN (consumers must not use the heading), rad."""
    heading_known_sigma_rad: float = 12.0 * _DEG
    """UNKNOWN is left only once the yaw 1σ is at most this (below heading_unknown_sigma_rad: a σ hovering at
    that limit does not flip the state; heading_state_hold.py), rad."""
    heading_state_hold_s: float = 5.0
    """A better heading state is published only after it has held this long (a worse one at once), s."""
    accel_bias_needs_heading: bool = True
    """True: the horizontal (body x, y) accelerometer bias learns from GNSS only while the heading is known (a
    trusted magnetometer, or a GNSS yaw confirmed it), so a wrong yaw's mis-projected GNSS acceleration cannot be
    taken up by the bias and hold a tilt error that a steady turn cannot separate from it (ins_core._gated_update;
    docs/estimator.md "A wrong heading must not teach the accelerometer bias"); the accelerometer z axis's lean and
    the x and y gyros' misalignment towards z, the other members of that error, wait with it."""
    mag_reentry_s: float = 20.0
    """A rejected magnetometer re-enters after its learned correction was consistent this long, s."""
    yaw_align_to_gnss_yaw: bool = True
    """Without a trusted magnetometer calibration (unknown, or worse than 3°) the filter's yaw is set to the GNSS
    yaw the first time that yaw is valid, before the filter has learned its biases against the magnetometer's
    heading (PX4 EKF2 aligns the yaw to its EKF-GSF when it has no magnetometer heading; ArduPilot EKF3 aligns
    to it once 5 valid fixes are seen when the GSF is its yaw source). Not counted against `yaw_reset_max`:
    that cap is for the emergency resets of a heading that was held."""
    start_rerun_max_s: float = 0.0
    """Without a trusted magnetometer calibration, the samples and fixes of the filter's first this many seconds are
    kept, and at the alignment to the first valid GNSS yaw with the magnetometer rejected the filter runs them again
    from its first sample under that yaw carried back (start_rerun.py), so that the first turn teaches the gyro
    biases against a heading the GNSS found instead of the magnetometer's. 0 (the default): never — on, the car's
    vertical gyro bias comes out of its first turn stated too well known (docs/gnss.md "The start run again under
    the GNSS yaw"); 60 is the figure measured there."""
    yaw_reset_max: int = 3
    """At most this many resets of the yaw to the GNSS yaw per run (ArduPilot EK3_GSF_RST_MAX 2)."""
    yaw_reset_spacing_s: float = 20.0
    """... at least this far apart, s."""
    heading_confirm_gsf_sigma_rad: float = 5.0 * _DEG
    """Without a trusted magnetometer (calibration unknown or worse than 3°, or rejected since the heading was last
    confirmed) the filter's yaw σ is kept at least the GNSS yaw's until a GNSS yaw this accurate has confirmed the
    filter's heading (within their joint 3σ): a linearised filter pulled in from tens of
    degrees shrinks its σ faster than its error. ArduPilot's compass learning waits for the same 5°
    (`Compass_learn.cpp`, YAW_ACCURACY_THRESHOLD_DEG). A yaw that was set to the GNSS yaw (`yaw_align_to_gnss_yaw`)
    was not pulled in: `accel_bias_gsf_sigma_rad` confirms it for the filter, but the published σ keeps the GNSS
    yaw's until a GNSS yaw this accurate agrees: the bank that set and confirmed that yaw may be 10° wide, and the
    fixes pull it through the same linearised update (docs/gnss.md)."""
    accel_bias_gsf_sigma_rad: float = 10.0 * _DEG
    """With `accel_bias_needs_heading`, the horizontal accelerometer bias learns again once a GNSS yaw this accurate
    agrees with the filter's heading (within their joint 3σ), or a trusted magnetometer holds it. Looser than
    `heading_confirm_gsf_sigma_rad`: a boat's GNSS yaw seldom gets below 5° (its accelerations are small), and held
    that long the bias is learned too late for the heading; chosen on held-out boat seeds (docs/estimator.md "A
    wrong heading must not teach the accelerometer bias")."""
    mag_rotation_gyro_bias: bool = True
    """Learn the vertical gyro bias from how the magnetometer's field turns in the body against the gyro's heading
    (mag_rotation.py): the hard iron cancels in the field's change, so an uncalibrated or learning magnetometer
    still sees the bias on straight legs, where the GNSS says nothing of the yaw."""
    accel_axes_heading_sigma_rad: float = ACCEL_MISALIGNMENT_SIGMA_RAD
    """1σ of the accelerometer's x–y cross-axis misalignment, rad: a GNSS-aided heading is the accelerometer's
    axes' heading, off by that much (accel_axes_heading.py), and once GNSS has aided the published yaw σ carries
    it (ADIS16405-class factory alignment, accel_axes_tilt.ACCEL_MISALIGNMENT_SIGMA_RAD: the same figure as
    `accel_axes_tilt_sigma_rad`'s). 0: not carried."""
    accel_axes_tilt_sigma_rad: float = ACCEL_MISALIGNMENT_SIGMA_RAD
    """1σ of each off-diagonal element of the accelerometer's misalignment, rad: ins's tilt is the accelerometer's
    axes' tilt, off by m_yz (roll) and m_xz (pitch) when level (accel_axes_tilt.py), and the published roll and
    pitch σ carry it (ADIS16405-class factory alignment, accel_axes_tilt.ACCEL_MISALIGNMENT_SIGMA_RAD: the same
    figure as `accel_axes_heading_sigma_rad`'s). It is also the prior σ of the z axis's lean states m_zx, m_zy
    (ins_core.E_AZ_LEAN). 0: not carried, and the lean states stay at zero."""
    published_yaw_slew_rad_s: float = 2.0 * _DEG
    """The published yaw follows the filter's corrections at no more than this rate beyond the vehicle's own
    rotation: a yaw reset or a fast correction is slewed in, the published σ covering what is left
    (published_heading.py), rad/s. The daemon's calibration-change slew uses the same 2 °/s."""
    # the heading measurement's noise and disturbance rejection (mag_noise_ut … mag_unavailable_s): inherited
    # from MagHeadingParams, shared with mekf

    # --- start-up and time gaps
    init_sigma_tilt_rad: float = 5.0 * _DEG
    init_sigma_yaw_rad: float = 10.0 * _DEG
    init_min_time_s: float = 1.0
    converged_tilt_rad: float = 1.0 * _DEG
    converged_yaw_rad: float = 3.0 * _DEG
    large_dt_s: float = 0.1
    reinit_dt_s: float = 2.0

    @property
    def calibration_sigma_rad(self) -> float:
        """The magnetometer calibration's heading 1σ in force (the uncalibrated figure when it is unknown)."""
        s = self.mag_calibration_sigma_rad
        return float(s) if math.isfinite(s) and s >= 0.0 else float(self.mag_uncalibrated_sigma_rad)

    @property
    def iron_soft_prior(self) -> float:
        """1σ prior of the learned soft iron on top of the calibration in force: a calibration whose heading 1σ is
        σ leaves soft iron of about σ (a scale or coupling error δ turns the heading by up to δ rad)."""
        return min(float(self.iron_soft_prior_sigma), self.calibration_sigma_rad)

    @property
    def mag_bias_tau(self) -> float:
        s = self.mag_calibration_sigma_rad
        return self.mag_bias_tau_s if math.isfinite(s) and s >= 0.0 else self.mag_uncalibrated_tau_s

    def to_array(self, declination_rad: float) -> np.ndarray:
        """The parameters as a 1-element ins_core.INS_PARAMS_DTYPE array (what the kernels take)."""
        arr = np.zeros(1, core.INS_PARAMS_DTYPE)
        p = arr[0]
        p["gyro_noise_rad_s_sqrt_hz"] = self.gyro_noise_rad_s_sqrt_hz
        p["gyro_bias_walk_rad_s_sqrt_s"] = self.gyro_bias_walk_rad_s_sqrt_s
        p["gyro_scale_walk_sqrt_s"] = self.gyro_scale_walk_sqrt_s if self.init_gyro_scale_sigma > 0 else 0.0
        p["gyro_scale_clip"] = self.gyro_scale_clip
        p["gyro_misalignment_walk_rad_sqrt_s"] = (self.gyro_misalignment_walk_rad_sqrt_s
                                   if self.init_gyro_misalignment_sigma_rad > 0 else 0.0)
        p["accel_noise_m_s2_sqrt_hz"] = self.accel_noise_m_s2_sqrt_hz
        p["accel_bias_walk_m_s2_sqrt_s"] = self.accel_bias_walk_m_s2_sqrt_s
        p["gyro_bias_clip_rad_s"] = self.gyro_bias_clip_rad_s
        p["accel_bias_clip_m_s2"] = self.accel_bias_clip_m_s2
        p["cov_period_s"] = self.cov_period_s
        p["earth_rotation"] = 1.0 if self.earth_rotation else 0.0
        if self.earth_model not in ("wgs84", "sphere"):
            raise ValueError(f"earth_model must be 'wgs84' or 'sphere', got {self.earth_model!r}")
        p["sphere"] = 1.0 if self.earth_model == "sphere" else 0.0
        p["mag_moves_tilt"] = 1.0 if self.mag_moves_tilt else 0.0
        p["mag_use"] = 1.0
        p["iron_soft_inv"] = np.eye(3)
        p["mag_bias_var_rad2"] = self.calibration_sigma_rad ** 2
        p["mag_bias_tau_s"] = self.mag_bias_tau
        p["mag_harmonic_walk_rad_sqrt_s"] = self.mag_harmonic_walk_rad_sqrt_s
        p["level_noise_m_s2"] = self.level_noise_m_s2
        p["level_reject_m_s2"] = self.level_reject_m_s2
        p["level_gate_rad"] = self.level_gate_rad
        p["level_lowpass_tau_s"] = self.level_lowpass_tau_s
        p["level_recover_s"] = self.level_recover_s
        p["turn_speed_m_s"] = self.turn_speed_m_s
        p["mag_enabled"] = 1.0 if self.mag_enabled else 0.0
        p["declination_rad"] = declination_rad
        p["lever_arm_m"] = np.asarray(self.lever_arm_m, dtype=float).reshape(3)
        p["lever_arm_cov_m2"] = arm_covariance_m2(self.lever_arm_sigma_m)
        p["lever_arm_corr_s"] = ARM_TERM_CORRELATION_S
        p["gate_chi2"] = chdtri([1.0, 2.0, 3.0], self.gate_false_alarm)
        p["reject_reset_s"] = self.reject_reset_s
        p["dead_reckon_s"] = self.dead_reckon_s
        p["outage_reset_s"] = self.outage_reset_s
        p["nav_drop_s"] = self.nav_drop_s
        p["max_delay_s"] = self.max_delay_s
        p["large_dt_s"] = self.large_dt_s
        p["reinit_dt_s"] = self.reinit_dt_s
        p["init_min_time_s"] = self.init_min_time_s
        p["converged_tilt_rad"] = self.converged_tilt_rad
        p["converged_yaw_rad"] = self.converged_yaw_rad
        p["gnss_timeout_s"] = self.gnss_timeout_s
        p["nav_init_sigma_tilt_rad"] = self.nav_init_sigma_tilt_rad
        p["accel_bias_learn"] = 1.0
        p["mag"] = mag.heading_params(self)
        return arr


DEFAULT_INS_PARAMS = InsParams()


_MAX_QUEUED = 16
_PYTHON_CALLED_KERNELS_LOADED = False   # Ins._load_python_called_kernels has run in this process

# where each output lies in the flat float64 view of an INS_OUT_DTYPE record
_OUT = AttitudeFields(core.INS_OUT_DTYPE)
_OUT_Q, _OUT_RATE, _OUT_SIGMA, _OUT_BIAS, _OUT_EULER = _OUT.q, _OUT.rate, _OUT.sigma, _OUT.bias, _OUT.euler
_OUT_RATE_TO_EULER = slice(_OUT_RATE.start, _OUT_EULER.stop)     # the step reads both (Ins._stepped)
assert _OUT_RATE.start < _OUT_SIGMA.start < _OUT_EULER.start
_STEP_SIGMA_YAW = _OUT_SIGMA.start + 2 - _OUT_RATE.start    # the filter's yaw σ in what the step reads
_OUT_VEL, _OUT_SIGMA_VEL, _OUT_SIGMA_POS, _OUT_ACCEL_BIAS = (float_field_slice(core.INS_OUT_DTYPE, n) for n in (
    "vel_ned_m_s", "sigma_vel_m_s", "sigma_pos_m", "accel_bias_m_s2"))
_OUT_SIGMA_YAW = _OUT_SIGMA.start + 2
_F_GNSS_AIDED, _F_INITIALISING = core.F_GNSS_AIDED, core.F_INITIALISING   # read per sample: no module lookup
_BLOCK_MAX = 64      # samples a block step takes at most (a daemon block holds ~12; a longer one takes more calls)


class Ins:
    """The aided estimator (Estimator protocol plus `update_gnss(fix)`).

    `update(sample) -> AttitudeEstimate` with `nav=NavState` once a fix has set velocity and position;
    `update_gnss(fix) -> int` (core.R_* bits of what happened; never raises on bad input, counts it in
    `gnss_counters`); `reset()`, `set_declination(rad)`, `relearn_field_reference()`; read-only `covariance`
    (31×31), `gyro_bias_rad_s`, `gyro_scale`, `gyro_misalignment_rad`, `accel_bias_m_s2`, `last_nis` (velocity,
    position); `heading_checks`, the latest heading checks' decisions (heading_monitor.HeadingCheckRecord).

    The class is the composition: it keeps the kernel's arrays and the published estimate, and hands the arrays to
    its parts, built in `__init__`: a sample goes through the compiled step (ins_core.py); a fix through `_fuse`:
    `InsGnssFusion` (ins_gnss_fusion.py: the fix into the state, the lever-arm check), then `HeadingSupervision`
    (heading_supervision.py: the heading checks and what they do to the yaw, the magnetometer's use and the
    learned iron), which resets through `YawReset` (yaw_reset.py) and switches the magnetometer's error states
    through `MagErrorStates` (mag_error_states.py). docs/architecture.md has what each part owns and is given.
    """

    name = "ins"

    def __init__(self, declination_rad: float = 0.0, params: InsParams | None = None, **overrides):
        self.params = with_overrides(params or DEFAULT_INS_PARAMS, overrides, "ins")
        self._declination = float(declination_rad)
        # state and parameters as 1-element record arrays (what the compiled step takes) and their records
        self._par_arr = self.params.to_array(self._declination)
        self._par = self._par_arr[0]
        self._x_arr = np.zeros(1, core.INS_STATE_DTYPE)
        self._x = self._x_arr[0]
        # fields read on every sample, as (1,) array views (indexing an array costs less than a record lookup)
        self._nav_ok = self._x_arr["nav_ok"]
        self._t_run_s = self._x_arr["t_run_s"]
        self._mag_use = self._par_arr["mag_use"]
        self._P = np.zeros((core.N_ERR, core.N_ERR))
        self._hist = np.zeros(core.H_LEN, core.INS_HISTORY_DTYPE)
        self._out_arr = np.zeros(1, core.INS_OUT_DTYPE)   # the step's outputs (what the compiled step takes)
        self._out = self._out_arr[0]
        # the same outputs as one flat float64 array: copied whole for an estimate (copying a record goes field
        # by field)
        self._out_flat = self._out_arr.view(np.float64)
        # what a built estimate reads of the state besides the outputs (`_build_estimate`): the attitude and the
        # low-passed specific force as flat float64 views; and its compiled terms through their entry point
        # (kernel_entry.py: called with these types only)
        self._q_true = _float_field_view(self._x_arr, "q")
        self._acc_ned_lp = _float_field_view(self._x_arr, "acc_ned_lp_m_s2")
        terms_args = (self._out_flat.copy(), self._q_true, self._acc_ned_lp, 0.0, False, False, True, 0.0, 0.0, 0.0,
                      0.0)
        self._published_terms = entry_point(published_terms, argument_types(published_terms, terms_args))
        self._initialised = False
        self._reinit_pending = False
        self._levelled_on_force = False    # the start levelled on the specific force: its first fix acts (_fuse)
        self._levelled_on_axis = False     # ... on a steady turn's rotation axis: its first fix's velocity is carried
        self._start_t_s = math.nan
        self._pending_flags = 0
        # the fixes offered (update_gnss): taken, queued until the samples reach them, or refused, and counted
        p = self.params
        self._intake = GnssFixIntake(max_queued=_MAX_QUEUED, use_vertical_velocity=p.use_vertical_velocity,
                                     min_h_acc_m=p.min_h_acc_m, min_v_acc_m=p.min_v_acc_m,
                                     min_s_acc_m_s=p.min_s_acc_m_s, reject_reset_s=p.reject_reset_s,
                                     on_reject=self._flag_gnss_rejected)
        self._fix_queue = self._intake.queue     # the intake's queue: is a fix waiting? (read on every sample)
        # what the accelerometer's axes add to an aided heading's published variance (accel_axes_heading.py)
        self._accel_axes_var_rad2 = accel_axes_heading_variance_rad2(self.params.accel_axes_heading_sigma_rad)
        self.gnss_counters: GnssCounters = self._intake.counters
        self._gsf_par_arr = _one_record_array(GsfParams(lever_arm_m=tuple(self.params.lever_arm_m)).to_record())
        self._gsf_arr = _one_record_array(new_gsf_state(GsfParams(), 0.0))
        self._gsf_par = self._gsf_par_arr[0]      # record views of the arrays the compiled step takes
        self._gsf = self._gsf_arr[0]
        self._par["gnss_yaw"] = 1.0 if self.params.gnss_yaw else 0.0
        self._step = core.fast_step(self._step_args_example())
        # a run of a block's samples through the kernel in one call (step_block), each sample's flags kept
        self._block_flags = np.zeros(_BLOCK_MAX, np.int64)
        self._step_block = fast_step_block(self._step_block_args_example())
        self._load_python_called_kernels()
        # a usable fix into the state, the lever-arm check, the velocity a yaw reset sets (ins_gnss_fusion.py)
        self._fusion = InsGnssFusion(self._x_arr, self._P, self._hist, self._par_arr, self._gsf_arr,
                                     self._gsf_par_arr, self._intake, told_arm_m=p.lever_arm_m, gnss_yaw=p.gnss_yaw,
                                     adopt_arm=p.lever_arm_adopt)
        self._lever_arm_fit = self._fusion.lever_arm_fit     # the same object for the filter's life
        # the state's resets when the heading is found wrong (yaw_reset.py)
        self._resets = YawReset(self._x, self._P, self._hist)
        # the iron learned on top of the calibration and its bookkeeping (iron_in_use.py); `_iron` is its learner
        # (the same object for the filter's life), which the heading checks read
        self._learned_iron = IronInUse(self.params.iron_prior_sigma_ut, self.params.iron_soft_prior)
        self._iron = self._learned_iron.learner
        # the magnetometer's calibration-error states: the heading harmonics and the frame tilt (mag_error_states.py)
        self._mag_errors = MagErrorStates(self._x, self._P, self._par, self._learned_iron)
        self._published = PublishedHeading(self.params.published_yaw_slew_rad_s)
        self._view = BuiltEstimateView(self._build_estimate)   # step()'s result: the estimate built on demand
        # before the first fix the calibration is checked by the circle its levelled field sweeps in turns
        self._field_circle = FieldCircleCheck(FieldCircleParams(mag_noise_ut=self.params.mag_noise_ut))
        # the heading checks at the fused fixes and what they do to the filter (heading_supervision.py)
        self._heading = HeadingSupervision(self.params, self._declination, self._x, self._P, self._par, self._hist,
                                           self._gsf_arr, self._learned_iron, self._mag_errors, self._resets,
                                           self._fusion, on_yaw_reset=self._flag_yaw_reset)
        self._heading.restart()
        self._set_field_circle()
        self._arm_start_recording()

    def _step_args_example(self) -> tuple:
        """Scratch arguments of the step's types (compiling it must not touch the filter's own arrays)."""
        gsf = _one_record_array(new_gsf_state(GsfParams(), 0.0))
        x = np.zeros(1, core.INS_STATE_DTYPE)
        x[0]["q"][0] = 1.0
        x[0]["t_last_s"] = 0.995
        return (x, np.eye(core.N_ERR), np.zeros(core.H_LEN, core.INS_HISTORY_DTYPE), self._par_arr.copy(),
                1.0, 0.0, 0.0, 0.0, 0.0, 0.0, -9.8, 20.0, 0.0, 40.0, 0, np.zeros(1, core.INS_OUT_DTYPE), gsf,
                self._gsf_par_arr)

    def _step_block_args_example(self) -> tuple:
        """Scratch arguments of the block step's types (the filter's own arrays stay untouched)."""
        x, P, hist, par = self._step_args_example()[:4]
        out = np.zeros(1, core.INS_OUT_DTYPE)
        gsf = _one_record_array(new_gsf_state(GsfParams(), 0.0))
        return (x, P, hist, par, np.zeros(1), np.zeros((1, 9)), np.zeros(1, np.int64), 0.0, out, gsf,
                self._gsf_par_arr, np.zeros_like(self._block_flags), PublishedHeading(1.0).state, 1.0)

    def _load_python_called_kernels(self) -> None:
        """Load the kernels this class calls from Python (numba's on-disk cache) for the types it calls them with,
        once per process, here at construction: a kernel's first call types its arguments and loads its machine
        code (milliseconds each, docs/daemon.md "Performance"), which would otherwise fall on the first fix, the
        first heading check and the first yaw reset in the daemon's event loop. Later calls go through numba's
        dispatcher (the same compiled code); a call with other types just loads its own at its first call."""
        global _PYTHON_CALLED_KERNELS_LOADED
        if _PYTHON_CALLED_KERNELS_LOADED:
            return
        x, par, gsf, gsf_par = self._x, self._par, self._gsf, self._gsf_par
        dx = np.zeros(core.N_ERR)
        for kernel, args in (
                (core.fuse_gnss, (self._x_arr, self._P, self._hist, self._par_arr) + (0.0,) * 10 + (True,) * 4),
                (gsf_reset, (gsf, gsf_par, 0.0, np.zeros(4))),
                (scalar_update, (self._P, dx, 0.0, 0.0, NAV_NO_GAIN_MASK, dx)),
                (core._apply_correction, (x, par, dx)),
                (core._correct_history, (self._hist, x, 0.0, dx, 0.0, 0.0, 0.0)),
                (core._rotate_attitude, (x["q"], 0.0, 0.0, 0.0)),
                (core.fill_outputs, (x, self._P, par, 0.0, 0.0, 0.0, self._out)),
                (input_validity, (0,) + (0.0,) * 9),
                (published_offset_step, (PublishedHeading(1.0).state, 1.0) + (0.0,) * 7),
                (published_reset, (PublishedHeading(1.0).state,)),
                (slew_step, (0.0,) * 5)):
            kernel.compile(tuple(kernel.typeof_pyval(a) for a in args))
        _PYTHON_CALLED_KERNELS_LOADED = True

    def _set_field_circle(self) -> None:
        """Start the circle check again (field_circle.py): it runs until the first fix, while a calibration states
        its heading error (with none, σ is π before the first fix and a check could add nothing)."""
        self._field_circle.reset()
        p = self.params
        self._field_circle_on = (p.mag_field_circle_check and p.mag_enabled
                                 and calibration_states_error(p.mag_calibration_sigma_rad))

    def _check_field_circle(self, t_s: float, m, f: int) -> None:
        """One levelled field (with the learned iron removed, as the kernel removes it) into the circle check."""
        m_used = self._iron.corrected(m)
        o = self._out_flat
        self._field_circle.add(t_s, float(o[_OUT_EULER.start]), float(o[_OUT_EULER.start + 1]), m_used,
                               max(float(o[_OUT_SIGMA.start]), float(o[_OUT_SIGMA.start + 1])), f)

    def field_circle_check(self) -> FieldCircleResult | None:
        """What the circle check found (field_circle.py) while it widens the published σ (before the first fix); None
        otherwise. Not the daemon's `field_circle()` (base.FieldCircleCheckedEstimator): ins levels its attitude
        without GNSS less well than mekf (docs/estimator.md "Known limits"), and a wrongly levelled field is no
        circle either, so a flag here widens σ — the heading is off — but does not show that the calibration is what
        is wrong, and the daemon does not say so."""
        checking = self._field_circle_on and not self._heading.ever_aided
        return self._field_circle.result if checking else None

    # ----------------------------------------------------------------------- Estimator protocol
    def reset(self) -> None:
        self._view.freeze()    # the estimate of the sample stepped last is the one it had (estimate_view.py)
        self._x_arr[:] = 0
        self._x["gyro_rotation_last_t_s"] = math.nan
        self._P[:] = 0.0
        self._initialised = False
        self._reinit_pending = False
        self._levelled_on_force = False
        self._levelled_on_axis = False
        self._pending_flags = 0
        self._intake.reset()
        self._published.reset()
        self._fusion.reset()     # an arm adopted in the run before is not kept
        self._heading.restart()
        self._set_field_circle()
        self._arm_start_recording()

    # ----------------------------------------------------------------------- the heading checks' counts
    @property
    def yaw_resets(self) -> int:
        """Yaw resets (the emergency ones and the alignments to the GNSS yaw) since the heading checks started."""
        return self._heading.yaw_resets

    @yaw_resets.setter
    def yaw_resets(self, n: int) -> None:
        self._heading.yaw_resets = n

    @property
    def gnss_yaw_alignments(self) -> int:
        """The planned alignments to the first valid GNSS yaw among `yaw_resets`."""
        return self._heading.gnss_yaw_alignments

    @property
    def heading_interventions(self) -> int:
        """Yaw resets and raised yaw variances (not Kalman updates) since the heading checks started."""
        return self._heading.heading_interventions

    # ----------------------------------------------------------------------- learned iron (persisted by the daemon)
    learned_iron_source = LEARNED_WITH_GNSS

    @property
    def unmodelled_iron_ut(self) -> float:
        return self.params.iron_unmodelled_ut

    def learned_iron(self) -> tuple[np.ndarray, np.ndarray]:
        """The hard iron learned on top of the calibration (body frame, µT) and its covariance (µT²)."""
        return self._iron.offset_ut.copy(), self._iron.cov_ut2.copy()

    def learned_soft_iron(self) -> tuple[np.ndarray, np.ndarray]:
        """The soft iron learned on top of the calibration, I + D (m = (I + D)·B + b, body frame), and the
        covariance of D's elements row by row (9×9; its prior where the motion has not observed it)."""
        return self._iron.soft_iron, self._iron.cov[3:, 3:].copy()

    def learned_iron_heading_sigma_rad(self) -> float:
        """The largest heading 1σ the learned iron leaves on a level vehicle at the filter's position (WMM), rad;
        NaN before a position is known."""
        field = self._heading.earth_field_ned() if self._initialised and self._x["nav_ok"] > 0 else None
        return math.nan if field is None else self._iron.level_heading_sigma_rad(field)

    def set_learned_iron(self, offset_ut, cov_ut2, soft_iron=None, soft_cov=None) -> None:
        """Start from a learned iron persisted earlier (same calibration): the hard iron and its covariance, and
        optionally the soft iron I + D and the 9×9 covariance of D (else D starts at its prior). Raises
        ValueError when not finite or a covariance is not positive definite."""
        self._view.freeze()    # the estimate of the sample stepped last is the one it had (estimate_view.py)
        self._end_start_recording_begun()
        self._learned_iron.restore(offset_ut, cov_ut2, soft_iron, soft_cov)
        self._heading.apply_learned_iron()

    def reset_learned_iron(self) -> None:
        """Forget the learned iron (a new calibration was accepted, or the operator reset it)."""
        self._view.freeze()    # the estimate of the sample stepped last is the one it had (estimate_view.py)
        self._end_start_recording_begun()
        self._learned_iron.forget()
        self._heading.apply_learned_iron()

    def set_mag_calibration_sigma(self, sigma_rad: float) -> None:
        """A new magnetometer calibration is in force (the daemon's calibration swap): its predicted heading
        error, 1σ rad (NaN: unknown). The heading checks start again with it; the filter's yaw variance is
        left to them (a changed heading is caught by the monitor and slewed in the published yaw). Told before
        the first sample, the filter is the one built with this calibration."""
        self._view.freeze()    # the estimate of the sample stepped last is the one it had (estimate_view.py)
        self._end_start_recording_begun()
        s = float(sigma_rad)
        self.params = replace(self.params, mag_calibration_sigma_rad=s if math.isfinite(s) and s >= 0.0 else math.nan)
        self._heading.set_params(self.params)
        self._heading.new_calibration(self._initialised)
        self._set_field_circle()

    def set_mag_calibration_frame_tilt_sigma(self, sigma_rad: float, heading_sigma_rad: float = 0.0) -> None:
        """The magnetometer calibration in force states its frame's tilt against the body, 1σ per axis, rad (0 or
        NaN: none, its frame is the body's), and the share of its heading error that tilt makes (rad, 0: not
        stated): the frame-tilt states start again from it, and the calibration's harmonic states from their prior
        without that share. Told after `set_mag_calibration_sigma` (which restarts them with the previous figures)."""
        self._view.freeze()    # the estimate of the sample stepped last is the one it had (estimate_view.py)
        self._end_start_recording_begun()
        s = float(sigma_rad)
        h = float(heading_sigma_rad)
        self.params = replace(self.params,
                              mag_calibration_frame_tilt_sigma_rad=s if math.isfinite(s) and s > 0.0 else 0.0,
                              mag_calibration_frame_tilt_heading_sigma_rad=h if math.isfinite(h) and h > 0.0 else 0.0)
        self._heading.set_params(self.params)
        self._heading.new_frame_tilt()

    def heading_report(self) -> HeadingReport:
        """What the heading checks did so far (replay's summary, the daemon's warning)."""
        return self._heading.report()

    @property
    def heading_state(self) -> HeadingState:
        return self._heading.publication.state

    @property
    def heading_checks(self) -> deque[HeadingCheckRecord]:
        """The latest heading checks' decisions, oldest first (heading_check_log.py)."""
        return self._heading.check_log.records

    def set_declination(self, declination_rad: float) -> None:
        """Magnetic declination (rad): the magnetometer heading is compared with true heading − declination,
        and the estimate's yaw/q are reported relative to magnetic north (as every estimator)."""
        self._view.freeze()    # the estimate of the sample stepped last is the one it had (estimate_view.py)
        self._end_start_recording_begun()
        self._declination = float(declination_rad)
        self._par["declination_rad"] = self._declination
        self._heading.set_declination(self._declination)

    def relearn_field_reference(self, heading_change_rad: float = math.nan) -> None:
        """As Mekf.relearn_field_reference: forget the learned field magnitude/dip; unaided, where the
        magnetometer calibration is the only heading reference, also raise the heading variance to cover
        `heading_change_rad` (NaN: not known) and the vertical gyro bias's to its initial uncertainty
        (mag_heading.widen_after_calibration_change). GNSS-aided the heading is not the old calibration's alone:
        the heading checks weigh the new calibration against the GNSS yaw (heading_monitor.py), and a filter
        heading moved at once to the new calibration's was rejected by them against a GNSS yaw that had not
        converged (docs/daemon.md "Calibration changes")."""
        self._view.freeze()    # the estimate of the sample stepped last is the one it had (estimate_view.py)
        self._end_start_recording_begun()
        mag.relearn_reference(self._mag_state(), RELEARN_GATE_OPEN_S)
        self._field_circle.reset()
        x = self._x
        if x["nav_ok"] > 0.0 and x["t_last_s"] - x["gnss_fused_t_s"] <= self.params.gnss_timeout_s:
            return
        down_body = quat_to_dcm(x["q"])[2]          # C_b^n's last row: NED down in the body frame
        mag.widen_after_calibration_change(self._P, core.E_YAW, core.E_BG, down_body,
                                           heading_change_rad, self.params.init_gyro_bias_sigma_rad_s)

    def _mag_state(self):
        """The magnetometer heading check's state (a view)."""
        return self._x["mag"]

    @property
    def lever_arm_m(self) -> tuple[float, float, float]:
        """The antenna's position from the IMU the filter was told (InsParams.lever_arm_m), body FRD, m."""
        return tuple(float(v) for v in self.params.lever_arm_m)

    @property
    def covariance(self) -> np.ndarray:
        """Error covariance 31×31 [δθ NED (rad), δv NED (m/s), δp NED (m), δb_g (rad/s), δb_a (m/s²), δs_g,
        δm_g (xy, xz, yx, yz, zx, zy, rad), δe_m (the magnetometer heading error's c0, c1, s1, c2, s2, rad),
        δε_m (the magnetometer calibration frame's tilt about body x, y, rad)]."""
        return self._P.copy()

    @property
    def gyro_bias_rad_s(self) -> np.ndarray:
        return self._x["gyro_bias_rad_s"].copy()

    @property
    def gyro_scale(self) -> np.ndarray:
        """Estimated gyro scale-factor errors per axis (ω_meas = (1 + s) ω + b), fraction."""
        return self._x["gyro_scale"].copy()

    @property
    def gyro_misalignment_rad(self) -> np.ndarray:
        """Estimated gyro misalignment M (3×3, zero diagonal; ω_meas = (I + diag(s) + M) ω + b), rad."""
        m = np.zeros((3, 3))
        for n in range(6):
            m[core.MIS_ROW[n], core.MIS_COL[n]] = self._x["gyro_misalignment_rad"][n]
        return m

    @property
    def accel_bias_m_s2(self) -> np.ndarray:
        return self._x["accel_bias_m_s2"].copy()

    @property
    def last_nis(self) -> tuple[float, float]:
        """Normalised innovation squared of the last velocity and position fusion attempts."""
        return float(self._x["vel_gate"]["nis"]), float(self._x["pos_gate"]["nis"])

    def true_attitude_q_wxyz(self) -> np.ndarray:
        """The filter's own attitude quaternion, body → true-north NED."""
        return self._x["q"].copy()

    def update(self, sample: ImuSample) -> AttitudeEstimate:
        return self.step(sample).snapshot()

    def step(self, sample: ImuSample) -> EstimateView:
        """The hot path: process one sample like `update` and return the estimator's reused EstimateView; its
        `snapshot()` is the AttitudeEstimate `update` returns, built only when asked (estimate_view.py)."""
        g = sample.gyro_rad_s
        a = sample.accel_m_s2
        m = sample.mag_ut
        sflags = int(sample.flags)
        extra = 0
        if self._start_recording is not None:
            self._record_start(sample)
        if self._initialised:
            # each vector read with one call (nine element reads cost more): the same values as floats
            gx, gy, gz = g.tolist()
            ax, ay, az = a.tolist()
            mx, my, mz = m.tolist()
            f = self._step(self._x_arr, self._P, self._hist, self._par_arr, sample.t_s,
                           gx, gy, gz, ax, ay, az, mx, my, mz, sflags, self._out_arr, self._gsf_arr, self._gsf_par_arr)
            if not f & NEEDS_INIT:
                if self._fix_queue:
                    self._fuse_queued()       # before the estimate of this sample, as every fix before it
                if self._field_circle_on and not self._heading.ever_aided and sample.t_s >= self._field_circle.due_t_s:
                    self._check_field_circle(sample.t_s, m, f)
                return self._stepped(sample.t_s, f)
            self._initialised = False
            self._reinit_pending = True
            extra = f & ~NEEDS_INIT
        if not self._initialise(sample.t_s, g, a, m, sflags):
            self._view.set(sample.t_s, extra | self._pending_flags, False)
            return self._view
        return self._stepped(sample.t_s, self._after_init_flags() | extra)

    def step_block(self, t_s: np.ndarray, rows: np.ndarray,
                   sample_flags: np.ndarray) -> tuple[list, EstimateView] | None:
        """The samples t_s (n,) float64, rows (n, 9) float64 (gyro rad/s, accel m/s², mag µT; C-contiguous) and
        sample_flags (n,) int64 stepped from the first as `step` would step them one by one, in one compiled call
        as far as nothing between two samples needs Python (ins_step_block.py): up to a queued fix falling due, the
        field-circle check's next sample (before the first fix), a sample that needs the filter (re)started, at most
        _BLOCK_MAX. Returns the stepped samples' estimate flags
        (k of them, maybe none: step the next sample with `step`) and the view, left at the last of them (None:
        none is stepped in a run while the filter is not started or records its start: step the samples with
        `step`); a
        caller that hands on each sample's estimate sets the view to each in turn (`view.set(t_s[j], flags[j],
        True)`): its flags are that sample's, but a snapshot built from it is the last sample's (the filter has
        moved on), so a caller that builds one at every sample steps sample by sample. Output-identical to `step`
        (tests/test_ins_step_block.py)."""
        if not self._initialised or self._start_recording is not None:     # the start's recording keeps every sample
            return None
        queue = self._fix_queue
        # `step` fuses a queued fix after the first sample that reaches it (the intake queues only fixes ahead of
        # the samples), and before the first fix checks the field circle at the first sample from its due time on:
        # that sample is stepped alone
        stop_t_s = float(queue[0].t_s) if queue else math.inf
        if self._field_circle_on and not self._heading.ever_aided:
            stop_t_s = min(stop_t_s, self._field_circle.due_t_s)
        published = self._published
        k = self._step_block(self._x_arr, self._P, self._hist, self._par_arr, t_s, rows, sample_flags, stop_t_s,
                             self._out_arr, self._gsf_arr, self._gsf_par_arr, self._block_flags, published.state,
                             published.max_rate_rad_s)
        if not k:
            return [], self._view
        flags = self._block_flags[:k].tolist()
        # what `_after_step` does besides the slew (the kernel's): the flags held for the next estimate go with the
        # first sample, the first aided sample is told to the heading checks (which only the field-circle check,
        # run before the first fix and so never in a run then, reads at a sample)
        if self._pending_flags:
            flags[0] |= self._pending_flags
            self._pending_flags = 0
        if not self._heading.ever_aided and any(f & _F_GNSS_AIDED for f in flags):
            self._heading.gnss_aided()
        self._view.set(float(t_s[k - 1]), flags[-1], True)
        return flags, self._view

    # ----------------------------------------------------------------------- GNSS
    def update_gnss(self, fix: GnssFix) -> int:
        """Offer one fix. Returns core.R_* bits (0 when it was not fused or was held for later). Bad fixes
        (no fix, NaN fields, time not increasing, older than max_delay_s, χ² outliers) are counted in
        `gnss_counters`, logged, and flag GNSS_REJECTED on the next estimate; never raises."""
        self._view.freeze()    # the estimate of the sample stepped last is the one it had (estimate_view.py)
        if self._start_recording is not None:
            self._start_recording.add_fix(fix)
        if not self._intake.offer(fix, self._initialised, self._x["t_last_s"]):
            return 0
        return self._fuse(fix)

    def _fuse_queued(self) -> None:
        now = self._x["t_last_s"]
        while (fix := self._intake.pop_due(now)) is not None:
            self._fuse(fix)

    def _flag_yaw_reset(self) -> None:
        """The heading checks reset the yaw (HeadingSupervision.reset_yaw): the next estimate says so."""
        self._pending_flags |= int(EstimateFlags.YAW_RESET)

    def _flag_gnss_rejected(self) -> None:
        """A fix was refused or rejected (GnssFixIntake): the next estimate says so."""
        self._pending_flags |= int(EstimateFlags.GNSS_REJECTED)

    def _fuse(self, fix: GnssFix) -> int:
        """Fuse one fix whose time the IMU samples have reached (InsGnssFusion.fuse), then run the heading checks
        that a fused or rejected velocity allows. Returns core.R_* bits (0 when nothing was usable)."""
        p = self.params
        res, arm_adopted = self._fusion.fuse(fix)
        if res & core.R_NAV_INIT and self._levelled_on_force:
            self._widen_for_turn_lean()
        elif res & core.R_NAV_INIT and self._levelled_on_axis:
            self._levelled_on_axis = False
            carry_over_fix_delay(self._x)      # levelled on a turn's axis the attitude is right: the fix is late
            self._couple_start_yaw_to_tilt()
        if arm_adopted:
            # the heading, bent by the wrong arm, is found again as at the start: unconfirmed, aligned to the
            # bank's yaw once valid
            self._heading.confirmation.arm_adopted()
        if p.heading_monitor and p.mag_enabled and res & (core.R_VEL_FUSED | core.R_VEL_REJECTED):
            self._heading.check(float(fix.t_s))
        elif not p.mag_enabled and res & (core.R_VEL_FUSED | core.R_VEL_REJECTED):
            self._heading.floor_yaw_sigma_without_magnetometer(float(fix.t_s))
        return res

    def lever_arm_fit(self) -> LeverArmFitResult | None:
        """The lever-arm check over the latest velocity fixes (lever_arm_fit.py), None before it has enough."""
        return self._fusion.result()

    def lever_arm_adopted_m(self) -> np.ndarray | None:
        """The correction to the told arm the lever-arm check adopted (body FRD m: the filter fuses at told + it),
        None while none is: what `lever_arm_fit()` says as `adopted_m` once `arm_adopted`, without making the fit
        (a fit over the window's fix pairs, which the daemon's 10 Hz housekeeping would make after every fix)."""
        fit = self._lever_arm_fit
        return fit.correction_m.copy() if fit.adoptions else None

    # ----------------------------------------------------------------------- internals
    def _initialise(self, t_s, g, a, m, sample_flags: int) -> bool:
        """Start the filter from one sample (levelled on the accelerometer, heading from the magnetometer when it
        is used), or restart it after a gap keeping what it had learned. False, nothing changed, when the sample
        cannot level it (no valid gyro or accelerometer, or a specific force far from gravity)."""
        valid = input_validity(sample_flags, g[0], g[1], g[2], a[0], a[1], a[2], m[0], m[1], m[2])
        if not (valid & IN_ACC_OK) or not (valid & IN_GYRO_OK):
            return False
        an = float(np.linalg.norm(a))
        if an < 2.0 or an > 30.0:
            return False
        p = self.params
        use_mag = bool(valid & IN_MAG_OK) and p.mag_enabled
        kept = learned_to_keep(self._x, self._reinit_pending)
        # in a steady turn: along its axis
        a_level = levelling_force(a, g - kept.gyro_bias_rad_s, 3.0 * p.init_accel_bias_sigma_m_s2,
                                  p.init_gyro_bias_sigma_rad_s)
        q0 = initial_true_attitude(a_level, m if use_mag else None, self._declination)
        if self._reinit_pending:
            self._start_recording = None     # a restart after a gap is no start to run again
        fresh_state(self._x_arr, t_s, q0, g, a, m if valid & IN_MAG_OK else np.nan)
        start_sensor_errors(self._x, kept)
        # the biases are also the last confirmed ones (what a yaw reset goes back to) and the start-up ones
        keep_bg = kept.gyro_bias_rad_s
        self._heading.confirmation.start_biases(keep_bg, kept.accel_bias_m_s2)
        first_history_row(self._x, self._hist, t_s, q0, g, keep_bg)
        start_mag_reference(self._x, kept, p.mag_min_undisturbed_s)
        self._levelled_on_force = a_level is a or np.array_equal(a_level, a)
        self._levelled_on_axis = not self._levelled_on_force
        axis_sigma = (axis_levelling_sigma_rad(g - kept.gyro_bias_rad_s, p.init_gyro_bias_sigma_rad_s)
                      if self._levelled_on_axis else 0.0)
        initial_covariance(self._P, p, use_mag, levelling_lean(a_level, m if use_mag else None, p.level_noise_m_s2),
                           axis_sigma)
        self._start_t_s = float(t_s)
        self._heading.restart_calibration_error_states()
        self._restart_companions(t_s)
        if self._rerun is not None:
            self._start_under_gnss_yaw()
        self._initialised = True
        core.fill_outputs(self._x, self._P, self._par, g[0] - keep_bg[0], g[1] - keep_bg[1], g[2] - keep_bg[2],
                          self._out)
        return True

    def _widen_for_turn_lean(self) -> None:
        """The first fix of a start levelled on the specific force, once: levelled again on it less the turn's
        centripetal acceleration while the attitude is still the start's (within the levelling's low-pass time:
        later the filter has levelled and checked the magnetometer over more than one sample), or its tilt 1σ
        widened (ins_start.first_fix_in_turn) and the magnetometer's yaw coupled to it (`_couple_start_yaw_to_tilt`);
        a new attitude starts the published heading again from the filter's, flagged as a yaw reset."""
        self._levelled_on_force = False
        p = self.params
        yaw_from_mag = p.mag_enabled and self._rerun is None
        soon = float(self._x["t_last_s"]) - self._start_t_s <= p.level_lowpass_tau_s
        if first_fix_in_turn(self._x, self._P, self._hist, p, self._declination, yaw_from_mag, soon):
            self._published.reset()
            self._pending_flags |= int(EstimateFlags.YAW_RESET)
            return
        if self._heading.confirmation.calibration_untrusted:
            return      # the yaw's 1σ is the untrusted calibration's (up to π), a GNSS yaw aligns it (start_rerun.py)
        self._couple_start_yaw_to_tilt()    # the fix widened the tilt the magnetometer's yaw was read at

    def _couple_start_yaw_to_tilt(self) -> None:
        """The first fix of a start (levelled on a turn's axis, or on the specific force and not levelled again),
        its yaw from the magnetometer: until now the heading row had no tilt part (ins_core `_mag_heading_row`:
        heading only before the first fix), so the yaw's 1σ says the field's heading error alone while the yaw is
        off by the tilt's error through the dip as well (the fix widened the tilt to what levelling cannot exclude,
        not the yaw); from here on the row carries the tilt, so P must say that the yaw's error is the tilt's
        through the dip (ins_start.couple_yaw_to_tilt; docs/estimator.md "startsig" and "the start's yaw coupled
        to its tilt")."""
        if not (self.params.mag_enabled and self._rerun is None):
            return
        row = tilt_through_dip_row(self._x["q"], self._x["mag_last_ut"])
        if row is not None:
            couple_yaw_to_tilt(self._P, row)

    # ----------------------------------------------------------------------- the start run again (start_rerun.py)
    def _arm_start_recording(self) -> None:
        """Keep the samples and fixes from the first sample on, when an alignment to the GNSS yaw may follow."""
        p = self.params
        on = (p.start_rerun_max_s > 0.0 and p.mag_enabled and p.heading_monitor and p.gnss_yaw
              and p.yaw_align_to_gnss_yaw)
        self._start_recording = StartRecording(p.start_rerun_max_s) if on else None
        self._rerun = None
        self._iron_at_start = None

    def _end_start_recording_begun(self) -> None:
        """What is told after the first sample (a calibration, an iron, the declination) would not be told to a
        start run again: the recording ends."""
        if self._start_recording is not None and self._start_recording.events:
            self._start_recording = None

    def _record_start(self, sample: ImuSample) -> None:
        """Before a sample is stepped: the start is run again if the alignment asked for it since the last one,
        else the sample is kept (the learned iron as it was at the first)."""
        rec = self._start_recording
        if self._heading.rerun_due is not None:
            self._run_start_again()
            return
        if not rec.events:
            if not self._heading.confirmation.calibration_untrusted:    # no alignment will follow
                self._start_recording = None
                return
            self._iron_at_start = keep_iron(self._learned_iron)
        rec.add_sample(sample)
        if not rec.on:
            self._start_recording = None

    def _run_start_again(self) -> None:
        """The filter from its first sample again, under the GNSS yaw bank's yaw at the alignment carried back
        (`_start_under_gnss_yaw`), over the samples and fixes kept; the fixes are counted once. The published
        heading moves as at a yaw reset (flagged)."""
        gsf_yaw, gsf_var, t_end, lat = self._heading.rerun_due
        events = self._start_recording.take()
        counts = self._heading.counts()
        counters = GnssCounters(**vars(self.gnss_counters))
        put_back_iron(self._learned_iron, self._iron_at_start)
        self.reset()
        self._gsf_arr[0] = new_gsf_state(GsfParams(), 0.0)   # all of the bank as built (its reset keeps its tilt)
        self._start_recording = None
        self._rerun = (gsf_yaw, gsf_var, t_end, lat, [e for is_sample, e in events if is_sample], counts)
        for is_sample, e in events:
            if is_sample:
                self.step(e)
            else:
                self.update_gnss(e)
        self._rerun = None
        vars(self.gnss_counters).update(vars(counters))
        self._pending_flags |= int(EstimateFlags.YAW_RESET)
        log.info("ins: the start run again from its first sample under the GNSS yaw (%d samples and fixes)",
                 len(events))

    def _start_under_gnss_yaw(self) -> None:
        """The first sample of a start run again: the yaw turned to the bank's carried back (start_rerun.start_heading)
        with its covariance with the gyro biases and scale factors; the heading checks start with the magnetometer
        rejected (HeadingSupervision.start_rerun)."""
        gsf_yaw, gsf_var, t_end, lat, samples, counts = self._rerun
        x, P = self._x, self._P
        bg, sg = slice(core.E_BG, core.E_BG + 3), slice(core.E_SG, core.E_SG + 3)
        h = start_heading(x["q"], samples, t_end, gsf_yaw, gsf_var, lat, x["gyro_bias_rad_s"],
                          P.diagonal()[bg], P.diagonal()[sg])
        core._rotate_attitude(x["q"], 0.0, 0.0, h.dyaw_rad)
        self._hist[0]["q"] = x["q"]
        x["acc_ned_lp_m_s2"] = np.asarray(quat_to_dcm(x["q"]), dtype=float) @ x["acc_last_m_s2"]
        restart_uncorrelated(P, core.E_YAW, h.yaw_var_rad2)
        P[core.E_YAW, bg] = P[bg, core.E_YAW] = h.yaw_gyro_bias_cov
        P[core.E_YAW, sg] = P[sg, core.E_YAW] = h.yaw_gyro_scale_cov
        self._heading.start_rerun(counts)

    def _restart_companions(self, t_s) -> None:
        """What runs beside the filter starts again with it: no queued fixes, the published heading follows the
        filter, no fix velocity for a yaw reset; the GNSS yaw bank restarts, or after a short gap keeps its
        hypotheses and only moves its clock on."""
        self._intake.drop_queued()
        self._published.reset()
        self._published.state[FOLLOWING] = 0.0
        self._fusion.restart()
        if not self._reinit_pending or not self.params.gnss_yaw:
            gsf_reset(self._gsf, self._gsf_par, float(t_s), np.full(4, np.nan))
        else:
            self._gsf.t_s = float(t_s)     # a short gap: the bank keeps its hypotheses, its clock moves on

    def _after_init_flags(self) -> int:
        f = after_init_flags(self._reinit_pending, self.params.mag_enabled)
        self._reinit_pending = False
        return f

    def _stepped(self, t_s: float, f: int) -> EstimateView:
        """What moves with every sample (`_after_step`); the estimate itself is built on demand (`_build_estimate`)."""
        self._view.set(t_s, self._after_step(t_s, f), True)
        return self._view

    def _after_step(self, t_s: float, f: int) -> int:
        """What follows every stepped sample, given its flags: the flags held for the next estimate merged, the first
        aided sample told to the heading checks, the published-heading slew (it integrates over sample time, so what
        is published does not depend on how often an estimate is built; a run of samples steps it in its kernel,
        ins_step_block.py). Returns the flags."""
        if self._pending_flags:
            f |= self._pending_flags
            self._pending_flags = 0
        if not self._heading.ever_aided and f & _F_GNSS_AIDED:
            self._heading.gnss_aided()
        # nothing published since the filter started (INITIALISING from its start): the published heading follows
        # the filter, as _restart_companions left it reset (it moves only in `update`, not called until then)
        published = self._published
        if published.state[FOLLOWING] or not f & _F_INITIALISING:
            r = self._out_flat[_OUT_RATE_TO_EULER].tolist()     # one call: rate first, then σ, …, Euler angles last
            published.update(t_s, r[-1], r[-3], r[-2], r, r[_STEP_SIGMA_YAW])
            published.state[FOLLOWING] = 1.0
        return f

    def _build_estimate(self, t_s: float, f: int, initialised: bool) -> AttitudeEstimate:
        """The AttitudeEstimate of the sample stepped last (EstimateView.snapshot)."""
        if not initialised:
            return uninitialised_estimate(t_s, f)
        o = self._out_flat.copy()  # one fresh buffer; the estimate's arrays are views of it
        # the yaw σ's floors, the consider terms of the accelerometer's axes (the tilt ins levels is theirs: the x
        # and y axes' misalignment is in it, at the levelling's partials at the low-passed specific force, a turn's
        # too; a heading the GNSS has observed is theirs as well), the published heading's offset, the wrapped yaw
        # and the position in degrees: ins_published_terms.py, compiled
        heading = self._heading
        # before the first fix aided it, the calibration's heading error (calibration_heading.py)
        pre_aid = not heading.ever_aided and self.params.mag_enabled
        off = self._published.offset_rad
        navigating = self._nav_ok[0] > 0.0
        roll, pitch, yaw, yaw_true, sigma_yaw, lat_deg, lon_deg, h = self._published_terms(
            o, self._q_true, self._acc_ned_lp, heading.confirmation.unconfirmed_sigma_rad, navigating,
            self._lever_arm_fit.heading_bent, not (pre_aid or off), float(self.params.accel_axes_tilt_sigma_rad),
            self._accel_axes_var_rad2 if heading.ever_aided else 0.0, off, self._declination)
        if pre_aid or off:
            if pre_aid:
                sigma_yaw = math.sqrt(sigma_yaw ** 2 + self._pre_aid_heading_var_rad2())
            # the filter's yaw moved faster than the published one may: the σ covers the offset (slewed_yaw.py)
            o[_OUT_SIGMA_YAW] = self._published.published_sigma(sigma_yaw) if off else sigma_yaw
        nav = None
        if navigating:
            nav = NavState(o[_OUT_VEL], lat_deg, lon_deg, h, o[_OUT_SIGMA_VEL], o[_OUT_SIGMA_POS], o[_OUT_ACCEL_BIAS])
        return attitude_estimate(t_s, o, _OUT, roll, pitch, yaw, yaw_true, f,
                                 heading.publication.published(f, sigma_yaw, self._t_run_s, self._mag_use,
                                                               heading.monitor),
                                 nav, heading.publication.integrity)

    def _pre_aid_heading_var_rad2(self) -> float:
        """What the yaw variance adds before the first fix, rad²: the magnetometer calibration is the only heading
        reference and its error is not in the filter's σ (the checks that would show it need GNSS):
        calibration_heading.py; or, once the field has swept a circle in turns, the error its centre and shape show
        when that is more (field_circle.py). The harmonic states carry the calibration's error in the filter's σ:
        then only what the circle adds."""
        cal_var = calibration_heading_variance_rad2(self.params.mag_calibration_sigma_rad)
        add_var = cal_var
        if self._field_circle_on:
            add_var = self._field_circle.result.checked_var_rad2(cal_var)
        if self._par["mag_harmonics_on"] > 0.0:
            add_var = max(0.0, add_var - cal_var)
        return add_var


def _float_field_view(records: np.ndarray, name: str) -> np.ndarray:
    """The float64 field `name` of the first record of `records` as a flat float64 array sharing its memory."""
    sub, offset = records.dtype.fields[name][:2]
    if sub.base != np.float64:
        raise TypeError(f"{name}: not a float64 field")
    return np.ndarray(sub.itemsize // 8, np.float64, records, offset)


def _one_record_array(record) -> np.recarray:
    """A 1-element record array holding a copy of `record`."""
    arr = np.zeros(1, dtype=record.dtype).view(np.recarray)
    arr[0] = record
    return arr


__all__ = ["Ins", "InsParams", "DEFAULT_INS_PARAMS", "GnssCounters"]
