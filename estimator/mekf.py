"""`mekf`: ahrsd's default attitude estimator — a multiplicative (error-state) quaternion Kalman filter.

State: attitude quaternion (body FRD → NED) and gyro bias; error state δθ (NED frame, 3) and δb (3).
Initialised from a weighted Wahba solution of the first sample's gravity and field directions; then

* strapdown propagation of the bias-corrected gyro, covariance Φ P Φᵀ + Q;
* the accelerometer corrects **tilt only**: the specific force is low-pass filtered in the NED frame (linear
  acceleration averages out, gravity stays: VQF's idea); its vertical updates δθ_N, δθ_E with a gain forced
  to zero on heading; rejected when the low-passed |f| is far from g or the vertical far from the estimate,
  then held off until the low-pass has forgotten the push; optional turn-angle adaptive noise (fixed-wing);
* the magnetometer corrects **heading only** (the angle of the horizontal field in the estimated NED frame,
  gain forced to zero on tilt), so a magnetic disturbance cannot tilt the horizon; the field is checked
  against a learned reference (magnitude, dip, and at rest its direction in the body), rejected while it
  differs, and a consistently changed field is adopted after a while (as VQF does); a body-fixed offset (a
  magnet attached after calibration) is learned from rotation and subtracted while it explains why the
  field's norm and dip disagree with the reference;
* rest detection (gyro and accelerometer steady, noise-aware) makes every gyro sample a direct bias
  measurement with the noise measured at rest.

The per-sample step is compiled with numba (`mekf_core.py`: the one implementation of the algorithm).
Parameters: `MekfParams` (every field with unit and meaning); defaults `DEFAULT_MEKF_PARAMS`.
See docs/estimator.md for the design, tuning and the figures measured on BROAD.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ahrsd.core.sample import ImuSample

from . import mekf_core as core
from .accel_axes_tilt import ACCEL_MISALIGNMENT_SIGMA_RAD
from .accel_bias_prior import ACCEL_BIAS_SIGMA_UNCALIBRATED_M_S2
from ahrsd.core.estimate import AttitudeEstimate, EstimateFlags, HeadingState
from .filter_output import (AttitudeFields, after_init_flags, attitude_estimate, estimate_flags,
                            float_field_slice, uninitialised_estimate)
from .calibration_heading import calibration_heading_variance_rad2, calibration_states_error
from .estimate_view import EstimateView
from .field_circle import FieldCircleCheck, FieldCircleParams, FieldCircleResult
from .field_circle_correction import FieldCircleCorrection
from .initial_attitude import initial_attitude
from .mag_heading import RELEARN_GATE_OPEN_S, heading_params, relearn_reference, widen_after_calibration_change
from .mag_heading_params import MagHeadingParams
from .params import with_overrides
from .base import DEFAULT_UNMODELLED_IRON_UT, LEARNED_IN_TURNS
from .rotations import quat_to_dcm

_DEG = math.pi / 180.0


@dataclass(frozen=True)
class MekfParams(MagHeadingParams):
    """Tuning of the MEKF. SI units; angles in rad. `DEFAULT_MEKF_PARAMS` (ground vehicles, boats, handheld;
    one set for all of BROAD) and `FIXED_WING_MEKF_PARAMS` (sustained coordinated turns)."""

    # --- gyro (process noise)
    gyro_noise_rad_s_sqrt_hz: float = 2.0 * _DEG / 60.0
    """Angle random walk density, rad/s/√Hz. ADIS16405 datasheet ARW 2.0°/√hr = 5.8e-4 rad/√s;
    the BROAD IMU measures 0.006°/√s, well inside it."""
    gyro_bias_walk_rad_s_sqrt_s: float = 1e-5
    """Bias random walk density, rad/s/√s: reaches the ADIS16405 in-run bias stability (0.007°/s, datasheet)
    in about 100 s. Larger values let linear acceleration and field errors leak into the bias in motion
    (docs/estimator.md, how the defaults were chosen on BROAD)."""
    gyro_rate_noise_sqrt_s: float = 1e-3
    """Tilt process noise that grows with the rotation rate: (this · |ω|)² per second is added to the tilt
    variance rate, for the gyro's scale-factor and axis-misalignment errors (an error of a fraction e of the
    rate turns the attitude by e·|ω| per second), √s. It balances the acceleration-adaptive tilt noise in fast
    rotation, where the tilt must be corrected quickly although the apparent vertical swings (BROAD, chosen by
    cross-validation with acc_adaptive_gain: docs/estimator.md). Heading keeps the angle random walk only (its
    noise floor mag_heading_noise_rad covers the rest). 0 = off."""
    gyro_bias_clip_rad_s: float = 2.0 * _DEG
    """The bias estimate is clipped to ±this per axis (VQF biasClip); rest is not declared above it."""
    init_bias_sigma_rad_s: float = 0.5 * _DEG
    """1σ of the gyro bias at start-up (VQF biasSigmaInit)."""

    # --- accelerometer (tilt)
    acc_noise_m_s2: float = 0.15
    """Noise of the low-passed specific force as a gravity measurement in motion (residual linear
    acceleration after the low-pass), m/s²."""
    acc_noise_rest_m_s2: float = 0.05
    """... at rest: sensor noise only (BROAD/ADIS class: ~0.045 m/s² per sample), m/s²."""
    acc_turn_noise_gain: float = 0.0
    """Adaptive tilt noise for sustained acceleration: a centripetal acceleration ⟂ g tilts the apparent
    vertical by φ = acos(g/|f|) (|f| of the low-passed specific force), so the tilt measurement gets
    (gain·(φ − dead zone))² of extra variance. 0 by default (handheld motion: shaking also changes |f|, so
    the gain costs accuracy on BROAD); 1 in `FIXED_WING_MEKF_PARAMS`, where a coordinated 30° turn otherwise
    drags the horizon by the bank angle (figures of both in docs/estimator.md)."""
    acc_turn_dead_zone_rad: float = 0.0
    """Turn angles φ below this add no noise, rad."""
    turn_speed_m_s: float = 2.0
    """A plausible speed of the vehicle while it turns, m/s (a boat's or a walker's; 25 in
    `FIXED_WING_MEKF_PARAMS`), for the published 1σ only (the estimate does not depend on it): a turn at ω
    about the vertical leans the apparent vertical by atan(ω·v/g), which the accelerometer's norm cannot show
    and the filter cannot tell from a tilt (turn_lean.py). The least speed: a faster vehicle's is read from
    its turns (the force across its heading over the turn rate, turn_lean.track_turn_speed)."""
    acc_reject_m_s2: float = 2.0
    """The accelerometer is not used while the low-passed | |f| − g | exceeds this (sustained linear
    acceleration), m/s²."""
    acc_gate_rad: float = 15.0 * _DEG
    """Tilt innovation gate: the low-passed vertical may differ from the estimate by at most this, rad."""
    acc_gate_recover_s: float = 10.0
    """After this long without a tilt update the rejection is overridden (recovers from a wrong tilt), s.
    Longer than the 4 τ hold that follows every rejection."""
    acc_lowpass_tau_s: float = 1.5
    """Time constant of the low-pass of the specific force in the NED frame, s (0 = off). VQF uses 3 s as
    its only tilt smoothing; the Kalman gain adds its own, so half of that."""
    acc_adaptive_gain: float = 30.0
    """Acceleration-adaptive tilt noise (mekf_core, accelerometer update): the spread of the tilt innovation around
    its running mean (how much the low-passed vertical swings while a hand moves the sensor about) times this is
    added to the tilt measurement variance; the factor stands for the low-passed measurement's correlation
    over many samples. Dimensionless; 0 = off (the filter then leans toward every sustained push). Chosen by
    cross-validation on BROAD with gyro_rate_noise_sqrt_s (docs/estimator.md)."""
    acc_adaptive_tau_s: float = 2.0
    """Window (time constant) of the tilt innovation's running mean and spread, s."""

    # --- magnetometer (heading)
    mag_enabled: bool = True
    """False: 6-axis mode, heading from the gyro only (flag MAG_UNAVAILABLE)."""
    # the heading measurement's noise and disturbance rejection (mag_noise_ut … mag_unavailable_s): inherited
    # from MagHeadingParams, shared with ins
    mag_rest_change_ut: float = 0.5
    """At rest the body does not turn: if the low-passed body-frame field moves more than this from where it
    was when the rest began, something magnetic moved nearby and the field is not used until motion, µT
    (0.5 µT ≈ 1° of heading for a 27 µT horizontal field; the rest low-pass leaves ~0.1 µT of noise)."""
    mag_offset_tau_s: float = 60.0
    """Body-fixed field offset (a magnet or iron attached after calibration, mekf_core `_field_offset`):
    forgetting time constant of its online estimate, s; 0 = off. Learned from rotation, used only while it
    explains why the field's norm and dip disagree with the reference learned before
    (mag_offset_explain_ratio). Chosen by cross-validation on BROAD (docs/estimator.md)."""
    mag_offset_min_angle_rad: float = 20.0 * _DEG
    """Field snapshots are compared once the body has turned this far, rad."""
    mag_offset_use_sigma_ut: float = 2.0
    """The offset estimate is used once its 1σ (largest axis) is below this, µT."""
    mag_offset_lag_s: float = 0.005
    """Timing skew between magnetometer and gyro samples: a snapshot taken while turning at |ω| sees the field
    turned by |ω|·this, which enters the offset fit as |ω|·this·|m| of noise, s."""
    mag_offset_agree_tau_s: float = 2.0
    """Time constant of the running disagreement between the field and the reference (raw and corrected), s."""
    mag_offset_explain_ratio: float = 0.5
    """The offset is subtracted while the corrected field's running disagreement with the reference is below
    this fraction of the raw field's: a body-fixed offset must explain why the field disagrees."""

    # --- rest detection (bias learning)
    rest_gyro_th_rad_s: float = 2.0 * _DEG
    """Rest: gyro deviation from its low-pass below this (VQF restThGyr), rad/s."""
    rest_acc_th_m_s2: float = 0.5
    """Rest: specific force deviation from its low-pass below this (VQF restThAcc), m/s²."""
    rest_min_time_s: float = 1.5
    """Rest is declared after the conditions held this long (VQF restMinT), s."""
    rest_filter_tau_s: float = 0.5
    """Low-pass time constant of the rest detector (VQF restFilterTau), s."""
    rest_gyro_noise_floor_rad_s_sqrt_hz: float = 2e-5
    """At rest every gyro sample measures the bias, with the noise variance measured from the spread of the
    samples around their low-pass (so a rest of T s gives σ_bias ≈ noise density/√T for any gyro); this is
    the floor of that density, rad/s/√Hz (the BROAD IMU has 1e-4, the ADIS16405 5.8e-4)."""

    # --- start-up and time gaps
    init_sigma_tilt_rad: float = 5.0 * _DEG
    """1σ tilt after the Wahba initialisation, rad."""
    init_sigma_yaw_rad: float = 10.0 * _DEG
    """1σ heading after the Wahba initialisation (with a magnetometer), rad."""
    init_min_time_s: float = 1.0
    """INITIALISING is held at least this long after (re-)initialisation, s."""
    converged_tilt_rad: float = 1.0 * _DEG
    """... and until the 1σ tilt is below this, rad."""
    converged_yaw_rad: float = 3.0 * _DEG
    """... and the 1σ heading is below this (ignored without a magnetometer), rad."""
    heading_unknown_sigma_rad: float = 15.0 * _DEG
    """Above this yaw 1σ the estimate's heading state is UNKNOWN (a heading consumer cannot use it), rad."""
    mag_field_circle_correction: bool = True
    """When the circle check (mag_field_circle_check) finds the calibration wrong, learn the hard iron it shows and
    remove it from the field (field_circle_correction.py); False: only widen σ by it."""
    mag_calibration_sigma_rad: float = 0.0
    """The heading error the magnetometer calibration leaves, 1σ rad, added to the published yaw 1σ
    (calibration_heading.py): 0 = the input is calibrated (the library default); NaN = no calibration or its
    quality unknown, the heading is then UNKNOWN. The daemon passes its calibration's figure
    (`set_mag_calibration_sigma`)."""
    accel_bias_sigma_m_s2: float = ACCEL_BIAS_SIGMA_UNCALIBRATED_M_S2
    """The accelerometer bias the input still carries, 1σ per axis, m/s²: the published roll/pitch 1σ add
    its tilt b/g and the yaw 1σ tan(dip)·b/g (no state estimates it: at rest the levelling takes f/|f| as the
    vertical). The default is the ADIS16405's residual turn-on bias after its factory calibration, 5 mg (the
    simulator's draw, docs/simulation.md; the datasheet's uncalibrated worst case is 50 mg): an accelerometer
    without a calibration of its own. The daemon and `ahrsd replay --calibration` set the figure an accelerometer
    calibration in force leaves (`set_accel_bias_sigma`, calibration/accel_trust.py); 0 = the input is exactly
    calibrated."""
    accel_axes_tilt_sigma_rad: float = ACCEL_MISALIGNMENT_SIGMA_RAD
    """1σ of each off-diagonal element of the accelerometer's misalignment, rad: mekf levels on the direction of the
    specific force it measures, so its tilt is the accelerometer axes' tilt, and the published roll and pitch σ carry
    the misalignment at the low-passed force the filter levels on (accel_axes_tilt.accel_axes_tilt_variance_in_force_rad2;
    ins's `accel_axes_tilt_sigma_rad`, the same figure). 0: not carried."""
    large_dt_s: float = 0.1
    """A step longer than this (or not positive) is flagged LARGE_DT, s."""
    reinit_dt_s: float = 2.0
    """A gap longer than this re-initialises the filter from the next sample, s."""

    def to_record(self) -> np.ndarray:
        """The parameters as a mekf_core.MEKF_PARAMS_DTYPE record (0-d array; what the kernel takes): the
        fields of the same names, the magnetometer check's as a mag_heading record."""
        p = np.zeros((), core.MEKF_PARAMS_DTYPE)
        for name in core.MEKF_PARAMS_DTYPE.names:
            if name == "mag":
                p[name] = heading_params(self)
            elif name == "mag_offset_min_cos":
                p[name] = math.cos(self.mag_offset_min_angle_rad)
            elif name == "heading_calibration_var_rad2":
                p[name] = calibration_heading_variance_rad2(self.mag_calibration_sigma_rad)
            else:
                p[name] = getattr(self, name)
        return p


DEFAULT_MEKF_PARAMS = MekfParams()
"""The defaults: chosen on BROAD (handheld, all 15 trials, one set) and the simulated ADIS16405 scenarios."""

FIXED_WING_MEKF_PARAMS = replace(DEFAULT_MEKF_PARAMS, acc_turn_noise_gain=1.0, turn_speed_m_s=25.0)
"""For aircraft (sustained coordinated turns): tilt measurement de-weighted by the turn angle acos(g/|f|); the
published σ counts a turn's lean at a small aircraft's cruise speed."""


_TWO_PI = 2.0 * math.pi
_NOT_MAG_HEADING = int(EstimateFlags.INITIALISING | EstimateFlags.MAG_UNAVAILABLE)
_F64 = np.dtype(np.float64)
_NEEDS_INIT_OR_BAD = core.NEEDS_INIT | core.BAD_SHAPE


_OUT = AttitudeFields(core.MEKF_OUT_DTYPE)
_OUT_Q, _OUT_RATE, _OUT_SIGMA, _OUT_BIAS, _OUT_EULER = _OUT.q, _OUT.rate, _OUT.sigma, _OUT.bias, _OUT.euler


_RECORD_OF = (None, None)   # the last parameters turned into a record, and that record (`_params_record`)


def _params_record(params: MekfParams) -> np.ndarray:
    """`params.to_record()`, kept for the last parameters asked (frozen: the same object, the same record; a
    Mekf copies it into its buffer and never writes the kept one), so filters started on one set of parameters
    build it once. The pair is read and replaced whole: two threads starting filters get their own record."""
    global _RECORD_OF
    kept, rec = _RECORD_OF
    if kept is not params:
        rec = params.to_record()
        _RECORD_OF = (params, rec)
    return rec


def _as_f64(v) -> np.ndarray:
    return np.asarray(v, dtype=np.float64)


class Mekf:
    """The default estimator (Estimator protocol): `update(sample) -> AttitudeEstimate`.

    Also `run_batch(t, gyro, accel, mag)` for recordings (same step, one compiled loop), `reset()`,
    `set_declination(rad)`, and read-only `gyro_bias_rad_s` / `covariance`.
    """

    name = "mekf"

    def __init__(self, declination_rad: float = 0.0, params: MekfParams | None = None, **overrides):
        # no overrides: the given (frozen) parameters themselves, not a copy (`replace` builds every field again)
        base = params or DEFAULT_MEKF_PARAMS
        self.params = with_overrides(base, overrides, "mekf") if overrides else base
        self._built_accel_bias_sigma_m_s2 = self.params.accel_bias_sigma_m_s2     # set_accel_bias_sigma(None)
        # one record {state, parameters, outputs} for the one-sample kernel (one array to pass per call);
        # the three are views of it
        self._buf = np.zeros(1, core.MEKF_BUFFER_DTYPE)
        self._state = self._buf[0]["state"]
        off = core.MEKF_BUFFER_DTYPE.fields["state"][1]
        self._state_bytes = self._buf.view(np.uint8)[off:off + core.MEKF_STATE_DTYPE.itemsize]   # `_zero_state`
        self._buf[0]["par"] = _params_record(self.params)
        self._out = self._buf[0]["out"]
        # the outputs as one flat float64 array over the same memory: copied whole for an estimate (copying
        # a structured array goes field by field)
        self._out_flat = np.ndarray(core.MEKF_OUT_DTYPE.itemsize // 8, np.float64, buffer=self._buf,
                                    offset=core.MEKF_BUFFER_DTYPE.fields["out"][1])
        # the outputs the view hands out, as fixed views (a field lookup per read costs more than the step)
        self._q_out = self._out["q"]
        self._rate_out = self._out["rate_rad_s"]
        self._bias_out = self._out["gyro_bias_rad_s"]
        self._sigma_out = self._out["sigma_rpy_rad"]
        self._euler_out = self._out["euler_rad"]
        self._declination = float(declination_rad)
        self._initialised = False
        self._reinit_pending = False
        self._step = core.fast_step()
        self._fill_euler = core.fast_fill_euler()
        self._fill_after_init = core.fast_fill_after_init()
        self._euler_stale = False      # the step leaves the Euler outputs; they are filled when read
        self._t_s = math.nan
        self._bits = -1
        self._view = MekfView(self)
        # the calibration checked by the circle its levelled field sweeps in turns (field_circle.py)
        self._field_circle = FieldCircleCheck(FieldCircleParams(mag_noise_ut=self.params.mag_noise_ut))
        self._field_circle_on = False
        # the hard iron it finds, learned and subtracted from the field (field_circle_correction.py)
        self._iron = FieldCircleCorrection()
        self._iron_body_ut = None           # what is subtracted from the field (None: nothing)
        self._iron_t_s = math.nan
        self._set_field_circle()

    def _zero_state(self) -> None:
        """Every byte of the state 0 (0.0, False): what `self._buf["state"] = 0` leaves, which numpy does field
        by field, as one fill of its bytes."""
        self._state_bytes.fill(0)

    # ----------------------------------------------------------------------- Estimator protocol
    def reset(self) -> None:
        self._zero_state()
        self._initialised = False
        self._reinit_pending = False
        self._set_field_circle()

    def set_declination(self, declination_rad: float) -> None:
        self._declination = float(declination_rad)

    def relearn_field_reference(self, heading_change_rad: float = math.nan) -> None:
        """Forget the learned field reference (magnitude, dip, the at-rest body-frame field) after a
        magnetometer calibration change; attitude and gyro bias are kept, so nothing steps. The heading
        variance is raised to cover `heading_change_rad`, how far the new calibration moves the heading on the
        current sample, and, when that is beyond the heading's 3σ, the variance of the gyro bias about the
        vertical (learned from the old heading) to its initial value (mag_heading.widen_after_calibration_change;
        NaN: not known, the covariance is kept).

        The reference gates magnetic disturbances. Learned on the uncalibrated field of a vehicle with strong
        iron it does not match the now-correct field, which would be rejected as a disturbance until the
        candidate logic adopts it (mag_new_time_s of rotation) or mag_reject_max_s runs out — and the heading
        would then jump. After this call the next sample sets the reference again, and the field is used
        once it has matched it for mag_min_undisturbed_s. The heading then moves to the new calibration's
        at the filter's own rate: the heading innovation gate (mag_gate_sigma, ≈ 45° at the default tuning)
        stays open for RELEARN_GATE_OPEN_S so a larger change (first calibration of strong iron) is taken
        too; the magnitude/dip check still rejects disturbances meanwhile. The daemon bounds the rate at
        which the autopilot sees the change (docs/daemon.md "Calibration changes")."""
        s = self._state
        relearn_reference(s["mag"], RELEARN_GATE_OPEN_S)
        s["mag_rest_set"] = False   # the at-rest field is the old calibration's: take it again
        s["offset"] = np.zeros((), core.FIELD_OFFSET_DTYPE)   # a body-fixed offset learned against the old calibration
        down_body = quat_to_dcm(s["q"])[2]          # C_b^n's last row: NED down in the body frame
        widen_after_calibration_change(s["P"], core.E_HEADING, core.E_BIAS, down_body,
                                       heading_change_rad, self.params.init_bias_sigma_rad_s)
        self._set_field_circle()

    def set_mag_calibration_sigma(self, sigma_rad: float) -> None:
        """A magnetometer calibration is in force whose predicted heading error is `sigma_rad` (1σ; NaN: none, or
        its quality unknown): from the next estimate the published yaw 1σ includes it (calibration_heading.py),
        and the circle check (field_circle.py) starts again on it."""
        self.params = replace(self.params, mag_calibration_sigma_rad=float(sigma_rad))
        self._set_field_circle()        # it also states the calibration's variance to the kernel

    def set_accel_bias_sigma(self, sigma_m_s2: float | None) -> None:
        """The accelerometer bias the input still carries (1σ per axis, m/s²; None: no accelerometer calibration,
        the chip's figure this filter was built with): from the next estimate the published tilt and yaw 1σ carry
        it."""
        sigma = self._built_accel_bias_sigma_m_s2 if sigma_m_s2 is None else float(sigma_m_s2)
        if not (math.isfinite(sigma) and sigma >= 0.0):
            raise ValueError(f"accelerometer bias 1σ {sigma_m_s2!r}: expected a finite figure ≥ 0 m/s²")
        self.params = replace(self.params, accel_bias_sigma_m_s2=sigma)
        self._buf[0]["par"]["accel_bias_sigma_m_s2"] = sigma

    def _set_field_circle(self) -> None:
        """Start the circle check again (a new calibration, a reset). It runs while a calibration states its
        heading error: with none (σ π) there is nothing a check could add. A hard iron learned in turns is kept,
        taken up again as across a restart (set_learned_iron): it belongs to the magnetometer calibration, not
        to the filter's state, and the daemon's store (daemon/learned_iron.py calibration_changed) resets it
        when another magnetometer calibration or mounting comes into force — a gyro calibration or a filter
        reset keeps it (else the store's next save would write nothing over it)."""
        learned = self.learned_iron() if self._iron.active else None
        self._set_field_circle_afresh()
        if learned is not None:
            self.set_learned_iron(*learned)

    def _set_field_circle_afresh(self) -> None:
        self._field_circle.reset()
        self._iron.reset()
        self._iron_body_ut = None
        self._iron_t_s = math.nan
        p = self.params
        self._field_circle_on = (p.mag_field_circle_check and p.mag_enabled
                                 and calibration_states_error(p.mag_calibration_sigma_rad))
        self._buf[0]["par"]["heading_calibration_var_rad2"] = calibration_heading_variance_rad2(
            p.mag_calibration_sigma_rad)

    def _check_field_circle(self, t_s: float, m, f: int) -> None:
        """One levelled field (as the calibration gives it) into the circle check (at its own rate, after start-up);
        the hard iron it finds learned and moved in (field_circle_correction.py); the verdict and what the
        correction leaves into the published σ's calibration term."""
        self._read_euler()
        e, sig = self._euler_out, self._sigma_out
        roll, pitch = float(e[0]), float(e[1])
        check, iron = self._field_circle, self._iron
        if iron.restored and not math.isfinite(iron.radius_ut):
            # the horizontal field now, for a restored correction's σ (the attitude's yaw does not change it)
            field_ned = quat_to_dcm(self._state["q"]) @ (np.asarray(m, dtype=float) - iron.body_ut)
            iron.see_horizontal_field(math.hypot(field_ned[0], field_ned[1]))
        judged = check.add(t_s, roll, pitch, m, max(float(sig[0]), float(sig[1])), f)
        claimed = calibration_heading_variance_rad2(self.params.mag_calibration_sigma_rad)
        if judged and self.params.mag_field_circle_correction:
            iron.learn(check.result, claimed, t_s)
        if iron.active:
            iron.advance(t_s - self._iron_t_s if math.isfinite(self._iron_t_s) else 0.0, float(sig[2]))
            self._iron_t_s = t_s
            if iron.body_ut is not None:
                self._iron_body_ut = iron.body_ut
                check.correction_ut = (float(iron.applied_ut[0]), float(iron.applied_ut[1]))
            self._buf[0]["par"]["heading_calibration_var_rad2"] = max(check.result.checked_var_rad2(claimed),
                                                                      iron.heading_var_rad2())
        elif judged:
            self._buf[0]["par"]["heading_calibration_var_rad2"] = check.result.checked_var_rad2(claimed)

    # ----------------------------------------------------------------------- learned iron (persisted by the daemon)
    # base.IronLearningEstimator, so the daemon's one store (daemon/learned_iron.py) keeps, shows, accepts and
    # resets the correction learned in turns as it does ins's GNSS-learned iron.
    learned_iron_source = LEARNED_IN_TURNS
    unmodelled_iron_ut = DEFAULT_UNMODELLED_IRON_UT

    def learned_iron(self) -> tuple[np.ndarray, np.ndarray]:
        """The hard iron learned in turns (body frame, µT: the circle's centre, z 0) and its covariance (µT²:
        what is known of it horizontally, field_circle_correction.sigma_ut; 0 along z, which is not learned)."""
        iron = self._iron
        if not iron.active:
            return np.zeros(3), np.zeros((3, 3))
        return np.array([iron.target_ut[0], iron.target_ut[1], 0.0]), np.diag([iron.sigma_ut() ** 2] * 2 + [0.0])

    def learned_soft_iron(self) -> tuple[np.ndarray, np.ndarray]:
        """None is learned in turns: I and a zero covariance."""
        return np.eye(3), np.zeros((9, 9))

    def learned_iron_heading_sigma_rad(self) -> float:
        """The heading 1σ the correction still leaves (field_circle_correction.heading_var_rad2); NaN without one."""
        iron = self._iron
        return math.sqrt(iron.heading_var_rad2()) if iron.active and math.isfinite(iron.radius_ut) else math.nan

    def set_learned_iron(self, offset_ut, cov_ut2, soft_iron=None, soft_cov=None) -> None:
        """Start from a correction learned in turns in an earlier run on this calibration: subtracted from the
        first sample on, its σ the horizontal one of `cov_ut2` until this run's circle judges it. ValueError
        for what the turns do not learn (a soft iron, a vertical part) or what is not finite."""
        if not self.params.mag_field_circle_correction:
            raise ValueError("the hard iron is not learned in turns (mag_field_circle_correction off)")
        if soft_iron is not None and not np.array_equal(np.asarray(soft_iron, float), np.eye(3)):
            raise ValueError("a soft iron is not learned in turns")
        cov = np.asarray(cov_ut2, dtype=float).reshape(3, 3)
        self._iron.restore(offset_ut, math.sqrt(max(cov[0, 0], cov[1, 1])))
        self._iron_body_ut = self._iron.body_ut
        self._field_circle.correction_ut = (float(self._iron.applied_ut[0]), float(self._iron.applied_ut[1]))

    def reset_learned_iron(self) -> None:
        """Forget the correction (the operator's reset, or it was folded into the calibration): the field as the
        calibration gives it again, σ widened by the sinusoid the correction removed until the check judges
        again (and, when the calibration is still wrong, learns it again)."""
        iron = self._iron
        if not iron.active:
            return
        removed_var = iron.applied_heading_var_rad2()
        iron.reset()
        self._iron_body_ut = None
        self._iron_t_s = math.nan
        self._field_circle.correction_ut = (0.0, 0.0)
        par = self._buf[0]["par"]
        par["heading_calibration_var_rad2"] = float(par["heading_calibration_var_rad2"]) + removed_var

    def field_circle(self) -> FieldCircleResult | None:
        """What the circle check found of the calibration in force (field_circle.py); None while it does not run
        (no calibration figure, or switched off)."""
        return self._field_circle.result if self._field_circle_on else None

    @property
    def gyro_bias_rad_s(self) -> np.ndarray:
        return self._state["gyro_bias_rad_s"].copy()

    @property
    def field_offset_ut(self) -> np.ndarray:
        """Estimated body-fixed field offset (an attached magnet), µT; zeros while mag_offset_tau_s is 0."""
        return self._state["offset"]["b_ut"].copy()

    @property
    def covariance(self) -> np.ndarray:
        """Error covariance 6×6 [δθ NED (rad), δb (rad/s)]."""
        return self._state["P"].copy()

    def update(self, sample: ImuSample) -> AttitudeEstimate:
        self.step(sample)
        if self._bits >= 0:
            return self._estimate(self._t_s, self._bits)
        return self._estimate_uninitialised(self._t_s, -1 - self._bits)

    def step(self, sample: ImuSample) -> "MekfView":
        """The hot path: process one sample like `update` and return the estimator's reused `MekfView` — no
        result object is built. The view reads the latest estimate and changes at the next call;
        `view.snapshot()` gives the immutable AttitudeEstimate `update` returns (build it only when
        publishing)."""
        t_s = self._t_s = sample.t_s
        g = sample.gyro_rad_s
        a = sample.accel_m_s2
        m = sample.mag_ut
        extra = 0
        if self._initialised:
            # the vectors go to the kernel as they are when they are float64 (the kernel's entry point reads
            # any 8-byte dtype as float64 unchecked), else as float64 copies
            if not (g.dtype is _F64 and a.dtype is _F64 and m.dtype is _F64):
                g, a, m = _as_f64(g), _as_f64(a), _as_f64(m)
            # the flags as they are: the entry point reads an int (SampleFlags is one) as int64; the field with the
            # hard iron learned in turns removed (the check keeps the field as the calibration gives it)
            f = self._step(self._buf, t_s, g, a, m if self._iron_body_ut is None else m - self._iron_body_ut,
                           sample.flags)
            if not f & _NEEDS_INIT_OR_BAD:
                self._bits = f
                self._euler_stale = True
                if self._field_circle_on and t_s >= self._field_circle.due_t_s:
                    self._check_field_circle(t_s, m, f)
                return self._view
            if f & core.BAD_SHAPE:
                raise ValueError("ImuSample vectors must have 3 elements")
            self._initialised = False
            self._reinit_pending = True
            extra = f & ~core.NEEDS_INIT
        sflags = int(sample.flags)
        if self._iron_body_ut is not None:
            m = m - self._iron_body_ut      # the filter starts on the field with the learned hard iron removed
        if not self._initialise(t_s, g, a, m, sflags):
            self._bits = -1 - extra       # < 0: no estimate yet (snapshot() is the uninitialised estimate)
            self._view.q_wxyz = np.array([1.0, 0.0, 0.0, 0.0])
            return self._view
        self._bits = self._after_init_flags() | extra
        return self._view

    # ----------------------------------------------------------------------- batch (replay, benchmarks)
    def run_batch(self, t_s, gyro_rad_s, accel_m_s2, mag_ut, sample_flags=None):
        """Process arrays of samples (N,), (N,3)… with the same step as `update`, continuing from the current
        state; returns (q_wxyz (N,4), EstimateFlags bits (N,) int), bit for bit `update`'s. Samples before
        the filter could initialise have NaN quaternions. sample_flags: optional (N,) SampleFlags ints.
        Computes only what it returns: the published 1σ's unmodelled turn-lean terms are not tracked through
        the batch but set to an upper bound at its end (turn_lean `bound_pushes`), so an `update` after
        a batch publishes a 1σ no smaller than had every sample gone through `update`."""
        t = np.ascontiguousarray(t_s, dtype=np.float64)
        g = np.ascontiguousarray(gyro_rad_s, dtype=np.float64)
        a = np.ascontiguousarray(accel_m_s2, dtype=np.float64)
        m = np.ascontiguousarray(mag_ut, dtype=np.float64)
        n = len(t)
        sf = (np.zeros(n, dtype=np.int64) if sample_flags is None
              else np.ascontiguousarray(sample_flags, dtype=np.int64))
        # every row is written once: by an initialisation (NaN where none could be made) or by the kernel's step
        q = np.empty((n, 4))
        fl = np.zeros(n, dtype=np.int64)
        scratch_out = np.zeros(1, core.MEKF_OUT_DTYPE)
        i = 0
        while i < n:
            if not self._initialised:
                if self._initialise(t[i], g[i], a[i], m[i], int(sf[i])):
                    q[i] = self._q_out
                    fl[i] = self._after_init_flags()
                else:
                    q[i] = np.nan
                i += 1
                continue
            j = core.mekf_run(self._buf, scratch_out, t, g, a, m, sf, i, q, fl)
            if j < n:  # gap: re-initialise from sample j
                self._initialised = False
                self._reinit_pending = True
            i = j
        return q, fl

    # ----------------------------------------------------------------------- internals
    def _initialise(self, t_s, g, a, m, sample_flags: int) -> bool:
        """Wahba initialisation from one sample; False if the sample cannot initialise (no gravity)."""
        valid = core.input_validity(sample_flags, g[0], g[1], g[2], a[0], a[1], a[2], m[0], m[1], m[2])
        if not (valid & core.IN_ACC_OK) or not (valid & core.IN_GYRO_OK):
            return False
        an = float(np.linalg.norm(a))
        if an < 2.0 or an > 30.0:  # free fall / shock: no usable gravity direction
            return False
        p = self.params
        use_mag = bool(valid & core.IN_MAG_OK) and p.mag_enabled
        q0 = initial_attitude(a, m if use_mag else None)
        s = self._state
        keep_bias = s["gyro_bias_rad_s"].copy() if self._reinit_pending else np.zeros(3)
        keep_gref = s["g_ref_m_s2"] if self._reinit_pending and s["g_ref_m_s2"] > 0 else 0.0
        ms = s["mag"]
        keep_ref = (float(ms["ref_norm_ut"]), float(ms["ref_dip_rad"])) if self._reinit_pending else None
        self._zero_state()
        s["q"] = q0
        s["gyro_bias_rad_s"] = keep_bias
        P = s["P"]
        yaw_sigma = p.init_sigma_yaw_rad if use_mag else math.pi
        P[core.E_TILT_N, core.E_TILT_N] = P[core.E_TILT_E, core.E_TILT_E] = p.init_sigma_tilt_rad**2
        P[core.E_HEADING, core.E_HEADING] = yaw_sigma**2
        for i in range(3):
            P[core.E_BIAS + i, core.E_BIAS + i] = p.init_bias_sigma_rad_s**2
        s["t_last_s"] = t_s
        s["gyro_lp_rad_s"] = g
        s["acc_lp_m_s2"] = a
        if valid & core.IN_MAG_OK:
            s["mag_lp_ut"] = m
        s["g_ref_m_s2"] = keep_gref or an
        s["acc_ned_lp_m_s2"] = np.asarray(quat_to_dcm(q0), dtype=float) @ a
        s["unturned"]["f_m_s2"] = s["acc_ned_lp_m_s2"]
        s["gyro_last_rad_s"] = g
        if keep_ref is not None and keep_ref[0] > 0:
            ms["ref_norm_ut"] = ms["cand_norm_ut"] = keep_ref[0]
            ms["ref_dip_rad"] = ms["cand_dip_rad"] = keep_ref[1]
        # the Wahba output is already the best heading: count the field as matching from the start
        ms["undisturbed_t_s"] = p.mag_min_undisturbed_s
        self._initialised = True
        self._fill_out_after_init()
        self._view.q_wxyz = self._q_out   # valid from here until an initialisation fails
        return True

    def _fill_out_after_init(self) -> None:
        """The outputs of the state the initialisation set, filled as a step fills them (one output fill)."""
        self._fill_after_init(self._buf)
        self._euler_stale = False

    def _read_euler(self) -> None:
        """Fill the Euler outputs of the last step if it left them (`mekf_core.fill_euler`)."""
        if self._euler_stale:
            self._fill_euler(self._buf)
            self._euler_stale = False

    def _after_init_flags(self) -> int:
        f = after_init_flags(self._reinit_pending, self.params.mag_enabled)
        self._reinit_pending = False
        return f

    def _estimate(self, t_s: float, f: int) -> AttitudeEstimate:
        self._read_euler()
        o = self._out_flat.copy()  # one fresh buffer; the estimate's arrays are views of it
        roll, pitch, yaw = o[_OUT_EULER].tolist()  # Python floats: cheap arithmetic
        return attitude_estimate(t_s, o, _OUT, roll, pitch, yaw, yaw + self._declination, f,
                                 self._heading_state(f, o[_OUT_SIGMA.start + 2]))

    def _heading_state(self, f: int, yaw_sigma_rad: float) -> HeadingState:
        """MAGNETOMETER while the magnetometer is the heading reference and in use; UNKNOWN while initialising,
        without a magnetometer update for mag_unavailable_s, or when σ is beyond heading_unknown_sigma_rad."""
        if (f & _NOT_MAG_HEADING) or not self.params.mag_enabled \
                or not yaw_sigma_rad <= self.params.heading_unknown_sigma_rad:
            return HeadingState.UNKNOWN
        return HeadingState.MAGNETOMETER

    def _estimate_uninitialised(self, t_s: float, extra: int) -> AttitudeEstimate:
        return uninitialised_estimate(t_s, extra)


class MekfView(EstimateView):
    """The latest estimate of a `Mekf`, read in place (estimate_view.py: returned by `Mekf.step`; one per
    estimator, reused).

    Attributes read the estimator's output buffer when accessed, so they change at the next step; arrays are
    views of that buffer (copy what you keep). `snapshot()` returns the immutable AttitudeEstimate; the fields
    not read here (`nav`, `heading_state`, …) read it. Before the first usable sample (`valid` False) the
    angles are NaN, as in `update`'s estimate.

    `q_wxyz` is a plain attribute (a property call would cost a sixth of the step): the estimator sets it to
    its quaternion output when it initialises and to the identity when it cannot."""

    __slots__ = ("_mekf", "q_wxyz")

    def __init__(self, mekf: Mekf):
        self._mekf = mekf
        self.q_wxyz = np.array([1.0, 0.0, 0.0, 0.0])

    def snapshot(self) -> AttitudeEstimate:
        m = self._mekf
        if m._bits < 0:
            return m._estimate_uninitialised(m._t_s, -1 - m._bits)
        return m._estimate(m._t_s, m._bits)

    @property
    def valid(self) -> bool:
        return self._mekf._bits >= 0

    @property
    def t_s(self) -> float:
        return self._mekf._t_s

    @property
    def flags(self) -> EstimateFlags:
        b = self._mekf._bits
        return estimate_flags(b) if b >= 0 else EstimateFlags.INITIALISING | estimate_flags(-1 - b)

    def _angle(self, i: int) -> float:
        m = self._mekf
        if m._bits < 0:
            return math.nan
        m._read_euler()
        return float(m._euler_out[i])

    @property
    def roll_rad(self) -> float:
        return self._angle(0)

    @property
    def pitch_rad(self) -> float:
        return self._angle(1)

    @property
    def yaw_rad(self) -> float:
        return self._angle(2)

    @property
    def heading_mag_rad(self) -> float:
        return self._angle(2) % _TWO_PI

    @property
    def heading_true_rad(self) -> float:
        return (self._angle(2) + self._mekf._declination) % _TWO_PI

    @property
    def rate_body_rad_s(self) -> np.ndarray:
        m = self._mekf
        return m._rate_out if m._bits >= 0 else np.full(3, math.nan)

    @property
    def gyro_bias_rad_s(self) -> np.ndarray:
        m = self._mekf
        return m._bias_out if m._bits >= 0 else np.zeros(3)

    @property
    def sigma_rpy_rad(self) -> np.ndarray:
        m = self._mekf
        return m._sigma_out if m._bits >= 0 else np.full(3, math.pi)


__all__ = ["Mekf", "MekfView", "MekfParams", "DEFAULT_MEKF_PARAMS", "FIXED_WING_MEKF_PARAMS", "initial_attitude"]
