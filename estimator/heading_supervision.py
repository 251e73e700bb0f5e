"""ins.Ins's heading supervision: at each fused GNSS velocity, the magnetometer's heading and the GNSS yaw bank's
are weighed against the filter's yaw (heading_monitor.HeadingMonitor), and what follows is done — a yaw variance
floor, an emergency yaw reset or the planned alignment to the first valid GNSS yaw, a confirmation of the held
heading — then the magnetometer's use in the kernel is set (magnetometer_use.py), the iron is learned
(iron_in_use.py), the vertical gyro bias is measured from the magnetometer's turning (mag_rotation.py) and the
heading state and integrity are published (heading_publication.py). Without a magnetometer, the yaw's published σ
is floored by the GNSS yaw instead (`floor_yaw_sigma_without_magnetometer`).

The part owns the heading checks' parts (the monitor, the confirmation, the publication, the check log, the
bias-from-rotation window), the WMM field at the filter's position, the magnetometer variances the next check
trusts, and the counts of yaw resets and interventions. It is built with the kernel's state record, covariance,
parameter record and history and the GNSS yaw bank's state array (the filter's own, read and written in place, as
the kernel does), the learned iron (IronInUse), the magnetometer's error states (MagErrorStates), the state's resets
(YawReset) and the GNSS fusion (InsGnssFusion: the velocity a reset sets, the lever-arm check's verdict); it tells
the filter of a yaw reset through `on_yaw_reset` (the YAW_RESET flag of the next estimate). The parameters and the
declination in force are the filter's: it tells them here when they change (`set_params`, `set_declination`), and
when it was first GNSS-aided (`gnss_aided`).
"""

from __future__ import annotations

import logging
import math
from typing import Callable, NamedTuple

import numpy as np

from ahrsd.core.gravity import EARTH_RATE_RAD_S

from . import ins_core as core
from .calibration_heading import calibration_states_error
from .constrained_update import scalar_update
from .gsf_yaw import gsf_output_of
from .heading_check_log import HeadingCheckLog
from .heading_confirmation import HeadingConfirmation, gnss_yaw_floor
from .heading_monitor import HeadingMonitor, MonitorDecision, attitude_heading_variances, wrap_pi
from .heading_publication import HeadingPublication, HeadingReport
from .ins_gnss_fusion import InsGnssFusion
from .iron_in_use import IronInUse
from .kernel_entry import argument_types, entry_point
from .mag_error_states import MagErrorStates, harmonics_source, learned_floor_var_rad2
from .mag_rotation import MagRotationBias, window_tilt_sigma_rad
from .magnetometer_use import IronState, magnetometer_use
from .monitor_follow_up import heading_observable, monitor_follow_up
from .rotations import quat_to_dcm, quat_to_euler, rotvec_to_dcm
from .slow_floor import slow_floor_var_rad2
from .yaw_reset import YawReset

log = logging.getLogger("ahrsd.estimator.ins")    # the filter's own log: what the daemon's operator reads as ins's
_MAG_ROTATION_GATE = 9.0    # NIS above which a magnetometer-rotation bias measurement is not fused (3σ)
NAV_NO_GAIN_MASK = sum(1 << j for j in range(core.E_V, core.E_P + 3))   # velocity and position: no gain


class HeadingSupervision:
    """The heading checks at the fused fixes and what they do to the filter (see the module docstring)."""

    def __init__(self, params, declination_rad: float, x, P: np.ndarray, par, hist: np.ndarray, gsf_arr: np.ndarray,
                 learned_iron: IronInUse, mag_errors: MagErrorStates, resets: YawReset, fusion: InsGnssFusion,
                 on_yaw_reset: Callable[[], None]) -> None:
        self.params = params
        self._declination = float(declination_rad)
        # the kernel's state record, covariance, parameter record and history
        self._x, self._P, self._par, self._hist = x, P, par, hist
        self._gsf_arr = gsf_arr
        # the bank's output read through its entry point (kernel_entry.py: this array only): a record argument
        # costs several µs to unbox, an array a fraction of one
        self._gsf_output = entry_point(gsf_output_of, argument_types(gsf_output_of, (gsf_arr,)))
        self._learned_iron = learned_iron
        self._iron = learned_iron.learner     # the same object for the filter's life
        self._mag_errors = mag_errors
        self._resets = resets
        self._fusion = fusion
        self._lever_arm_fit = fusion.lever_arm_fit
        self._on_yaw_reset = on_yaw_reset
        # a fix has aided the filter since it started (told: `gnss_aided`; the filter reads it here too)
        self.ever_aided = False

    def set_params(self, params) -> None:
        """The filter's parameters changed (a new calibration's figures): the checks read these from now on."""
        self.params = params

    def set_declination(self, declination_rad: float) -> None:
        self._declination = float(declination_rad)

    def gnss_aided(self) -> None:
        """A fix has aided the filter since it started (a learned iron's error may be carried as the harmonics)."""
        self.ever_aided = True

    def report(self) -> HeadingReport:
        """What the heading checks did so far (replay's summary, the daemon's warning)."""
        return self.publication.report(self.monitor, self.yaw_resets)

    def new_calibration(self, initialised: bool) -> None:
        """A new magnetometer calibration is in force (its figures in `params`, told before): the checks start
        again with it, keeping the monitor's resets; the magnetometer's error states restart from its prior."""
        p = self.params
        self._learned_iron.new_calibration(p.iron_soft_prior)
        self.monitor = HeadingMonitor(p.calibration_sigma_rad, reentry_s=p.mag_reentry_s,
                                      max_resets=p.yaw_reset_max, reset_spacing_s=p.yaw_reset_spacing_s,
                                      resets=self.monitor.resets, last_reset_t_s=self.monitor.last_reset_t_s)
        self.confirmation.set_calibration(p.calibration_sigma_rad, self.monitor.trusted_sigma_rad)
        self._magnetometer_as_calibrated()
        self._par["mag_bias_tau_s"] = p.mag_bias_tau
        self.set_mag_harmonics()
        self.restart_calibration_error_states()    # the new calibration's error, independent of the old one's
        self.set_accel_bias_learning()
        if self._heading_checks_run:    # else the floor is none, or the one without magnetometer (no calibration's)
            c = self.confirmation
            c.unconfirmed_sigma_rad = c.unconfirmed_yaw_sigma(*self.yaw_and_gnss_yaw_now(initialised))

    def new_frame_tilt(self) -> None:
        """The calibration in force states a new frame tilt (its figures in `params`, told before): the frame-tilt
        states start again from it, and the calibration's harmonic states from their prior without its share."""
        p = self.params
        self._mag_errors.set_frame_tilt(p)
        if self._mag_errors.source == "calibration":
            # their prior leaves out what the frame-tilt states now carry
            self._mag_errors.restart_harmonics(p, self.field_ned, self._declination)
        self._mag_errors.restart_frame_tilt(p)

    def restart(self) -> None:
        """The heading checks start again (the filter built or reset): a new monitor, confirmation, publication and
        check log, no WMM field yet, the calibration's variances, the magnetometer fused, nothing aided yet."""
        p = self.params
        self.ever_aided = False
        self.monitor = HeadingMonitor(p.calibration_sigma_rad, reentry_s=p.mag_reentry_s,
                                      max_resets=p.yaw_reset_max, reset_spacing_s=p.yaw_reset_spacing_s)
        # whether a GNSS yaw has confirmed the heading, the alignment to it, the published σ's floor until then
        self.confirmation = HeadingConfirmation(
            align_to_gnss_yaw=p.yaw_align_to_gnss_yaw, mag_enabled=p.mag_enabled,
            checks_run=self._heading_checks_run, heading_confirm_sigma_rad=p.heading_confirm_gsf_sigma_rad,
            bias_confirm_sigma_rad=p.accel_bias_gsf_sigma_rad, gate_sigma=self.monitor.gate_sigma,
            calibration_sigma_rad=p.calibration_sigma_rad, trusted_sigma_rad=self.monitor.trusted_sigma_rad)
        # the heading state held at the check rate, the integrity figures, the first step rejection
        self.publication = HeadingPublication(p)
        self.check_log = HeadingCheckLog()     # the latest checks' records (`heading_checks`)
        self._field_key = None
        self.field_ned = None
        # an iron was learned or restored before the magnetometer's latest rejection: the learned iron may be what
        # the rejection found wrong, so a rejected magnetometer is not fused
        # (`magnetometer_use.rejected_magnetometer_fused`)
        self._iron_before_rejection = False
        self._mag_rotation = MagRotationBias(gyro_noise_rad_s_rthz=p.gyro_noise_rad_s_sqrt_hz)
        self._mag_rotation_on = p.mag_rotation_gyro_bias and p.heading_monitor and p.mag_enabled
        self._x["gyro_rotation_last_t_s"] = math.nan   # the kernel sums the gyro's rotation (ins_core.py)
        self.yaw_resets = 0
        self.gnss_yaw_alignments = 0
        self.heading_interventions = 0    # yaw resets and raised yaw variances (not Kalman updates)
        # set at an alignment with the magnetometer rejected: (the bank's yaw, its variance, the time of the last
        # sample stepped, the latitude); the filter's to take (start_rerun.py)
        self.rerun_due: tuple[float, float, float, float] | None = None
        self._rerun_first_gnss_yaw = False     # a start run again waits for its first valid GNSS yaw
        self._magnetometer_as_calibrated()
        self.set_accel_bias_learning()
        self.apply_learned_iron()
        self.set_mag_harmonics()

    def _magnetometer_as_calibrated(self) -> None:
        """The magnetometer as the calibration in force states it, until a check says otherwise: its variances for
        the next check's trust and the heading state, and in the kernel fused, moving the tilt as the parameters
        say, its slowly varying error at the calibration's variance."""
        p = self.params
        self._mag_var = p.calibration_sigma_rad ** 2
        self._mag_trust_var = p.calibration_sigma_rad ** 2
        self._par["mag_use"] = 1.0
        self._par["mag_moves_tilt"] = 1.0 if p.mag_moves_tilt else 0.0
        self._par["mag_bias_var_rad2"] = p.calibration_sigma_rad ** 2

    def apply_learned_iron(self) -> None:
        """The kernel removes the learned iron before its heading update: (I + D)⁻¹·(m − b); a learned iron's
        error is the learner's, not the calibration's harmonic states' (mag_error_states.harmonics_source); the kernel's field
        check takes its reference from the WMM field while an iron is learned (IronInUse.follow_field_reference)."""
        self._par["iron_ut"] = self._iron.offset_ut
        self._par["iron_soft_inv"] = self._iron.soft_iron_inverse
        self.set_mag_harmonics()
        self._learned_iron.follow_field_reference(self._x["mag"], self.field_ned)

    def set_mag_harmonics(self) -> None:
        """Which heading error the harmonic states carry now (mag_error_states.harmonics_source, from what the
        heading checks and the learned iron say), told to the kernel (MagErrorStates.select)."""
        p = self.params
        m = self.monitor
        source = harmonics_source(p, calibration_untrusted=self._calibration_untrusted,
                                  iron_learned=self._learned_iron.learned, ever_aided=self.ever_aided,
                                  iron_learning=m.learning, mag_rejected=m.mag_rejected, field_ned_ut=self.field_ned)
        self._mag_errors.select(p, source, self.field_ned, self._declination)

    def restart_calibration_error_states(self) -> None:
        """The magnetometer's error states back to their priors (MagErrorStates.restart)."""
        self._mag_errors.restart(self.params, self.field_ned, self._declination)

    def yaw_and_gnss_yaw_now(self, initialised: bool) -> tuple[float, float, float]:
        """What the unconfirmed-yaw floor is computed from (HeadingConfirmation.unconfirmed_yaw_sigma), now: the
        filter's yaw and the GNSS yaw bank's yaw and variance; before the filter has started, no yaw yet (its floor
        at construction)."""
        if not initialised:
            return 0.0, math.nan, math.nan
        gsf_yaw, gsf_var, _ = self.gnss_yaw()
        return float(quat_to_euler(self._x["q"])[2]), gsf_yaw, gsf_var

    def earth_field_ned(self) -> np.ndarray | None:
        """WMM field at the filter's position (µT, NED), looked up again when the position moves by ~1 km."""
        lat, lon, h = (math.degrees(self._x["lat_rad"]), math.degrees(self._x["lon_rad"]), float(self._x["h_m"]))
        key = (round(lat, 2), round(lon, 2), round(h, -2))
        if key != self._field_key:
            from ahrsd.core.wmm import earth_field
            try:
                self.field_ned = earth_field(lat, (lon + 180.0) % 360.0 - 180.0, h).ned_ut
            except ValueError:
                self.field_ned = None
            self._field_key = key
        return self.field_ned

    def check(self, t_s: float) -> None:
        """The heading checks at a fused fix, in order: the magnetometer's and the GNSS yaw bank's headings, the
        monitor's decision on them, what it does to the yaw (a floor, a reset or the alignment to the GNSS yaw, or
        a confirmation), the magnetometer's use in the kernel, the iron learning, then what is published."""
        x = self._x
        c_bn = quat_to_dcm(x["q"])
        yaw = math.atan2(c_bn[1, 0], c_bn[0, 0])
        yaw_var = float(self._P[core.E_YAW, core.E_YAW])
        m_body = self._iron.corrected(x["mag_last_ut"])
        # the position does not move within a check (its updates give no position gain): one WMM look-up
        field = self.earth_field_ned()
        if self._mag_rotation_on:
            self._mag_rotation_check(t_s, c_bn, field)
        mag_yaw, mag_var, noise, averaged = self._magnetometer_heading(c_bn, yaw, m_body)
        trust_var = self._magnetometer_trust_var(mag_var, noise, field)
        gsf_yaw, gsf_var, gsf_valid = self.gnss_yaw()
        slow_var = mag_var - noise - averaged if math.isfinite(mag_var) else math.nan
        d = self._monitor_decision(t_s, yaw, yaw_var, mag_yaw, mag_var, slow_var, trust_var, gsf_yaw, gsf_var,
                                   gsf_valid)
        yaw_reset_to = self._reset_or_confirm_yaw(t_s, d, yaw, gsf_yaw, gsf_var, gsf_valid)
        self.set_accel_bias_learning()
        self._set_magnetometer_use(d, mag_var, noise, trust_var, slow_var)
        # the monitor says no learning on a check that reset the yaw (c_bn is the attitude before the reset, P its
        # covariance after it): the next check learns with the new yaw
        iron_updates = self._iron.updates
        applied = False
        if self.params.iron_learning and self.monitor.learning and _finite3(m_body) and self._x["nav_ok"] > 0:
            applied = self._learn_iron(t_s, c_bn, field)
        if not applied:     # a learning step applied the iron and set the harmonics' source with it
            self.set_mag_harmonics()      # the iron learning may have ended here (harmonics_source)
        yaw_now = yaw if yaw_reset_to is None else wrap_pi(yaw_reset_to)
        self.publication.note_step_rejection(t_s, d.mag_step_rad, self.monitor.mag_rejected)
        self._publish_heading_checks(t_s, yaw_now, gsf_yaw, gsf_var, gsf_valid)
        self.check_log.add(t_s, d, float(self._P[core.E_YAW, core.E_YAW]), yaw_reset_to,
                            self._iron.updates > iron_updates)

    def _mag_rotation_check(self, t_s: float, c_bn: np.ndarray, field: np.ndarray | None) -> None:
        """The vertical gyro bias from the magnetometer's turning (MagRotationBias, mag_rotation.py): the gyro's
        rotation since the last check (less the bias estimate and the Earth's rotation, which turns the field with
        it) goes into the window; a completed window's b_z − b̂_z is fused as a measurement of the bias, less what
        the kernel's own magnetometer update already took from the same samples."""
        p = self.params
        x = self._x
        P = self._P
        dt = float(x["gyro_rotation_s"])      # the kernel's sum of raw rates: the bias is taken out here
        lat = float(x["lat_rad"])
        earth_rate = EARTH_RATE_RAD_S * np.array([math.cos(lat), 0.0, -math.sin(lat)])
        step = rotvec_to_dcm(x["gyro_rotation_rad"] - (x["gyro_bias_rad_s"] + c_bn.T @ earth_rate) * dt)
        x["gyro_rotation_rad"] = 0.0
        x["gyro_rotation_s"] = 0.0
        m = x["mag_last_ut"]
        m0, m1, m2 = m.tolist()
        if field is None or not (math.isfinite(m0) and math.isfinite(m1) and math.isfinite(m2)) \
                or x["nav_ok"] <= 0 or dt <= 0.0:
            self._mag_rotation.restart()
            return
        att = slice(core.E_TH, core.E_TH + 3)
        tilt, bias = slice(core.E_TILT_N, core.E_TILT_E + 1), slice(core.E_BA, core.E_BA + 3)
        # asked only when this check completes a window (P is not changed before it is): a 3×3 solve
        def tilt_sigma() -> float:
            return window_tilt_sigma_rad(P[tilt, tilt], P[tilt, bias], P[bias, bias])
        out = self._mag_rotation.add(t_s, m, c_bn, field, step, float(x["gyro_bias_rad_s"][2]), dt,
                                     self._iron.soft_iron, self._iron.largest_soft_iron_sigma, P[att, att],
                                     tilt_sigma)
        if out is None:
            return
        innovation, var = out
        span = self._mag_rotation.span_s
        if self._par["mag_use"] > 0.5 and span > 0.0:
            # the kernel fuses these samples as a heading with a slowly varying error of variance mag_bias_var:
            # over the window they told it the bias to about √2 σ / T; count only what is beyond that
            kernel_var = 2.0 * float(self._par["mag_bias_var_rad2"]) / span ** 2
            if var >= kernel_var:
                return
            var = 1.0 / (1.0 / var - 1.0 / kernel_var)
        i = core.E_BG + 2
        if innovation * innovation > _MAG_ROTATION_GATE * (P[i, i] + var):
            return
        # a measurement of the bias now: the attitude and the other biases follow through their covariance with
        # it; the velocity and position are left to the GNSS (their history is not kept for a correction)
        h = np.zeros(core.N_ERR)
        h[i] = 1.0
        dx = np.zeros(core.N_ERR)
        scalar_update(P, h, innovation, var, NAV_NO_GAIN_MASK, dx)
        core._apply_correction(x, self._par, dx)
        core._correct_history(self._hist, x, -math.inf, dx, 0.0, 0.0, 0.0)

    def _magnetometer_heading(self, c_bn: np.ndarray, yaw: float,
                              m_body: np.ndarray) -> tuple[float, float, float, float]:
        """The yaw the magnetometer (iron-corrected, body frame µT) gives with the attitude c_bn, its variance, the
        white (noise) part of that variance, and the part of the learned floor that the trust window averages away
        (slow_floor.py; 0 without a learned iron), rad²: (NaN, inf, 0, 0) when the field is not finite or has no
        horizontal component."""
        p = self.params
        mag_yaw = math.nan
        mag_var = math.inf
        noise = 0.0
        averaged = 0.0
        if _finite3(m_body):
            m_ned = c_bn @ m_body
            h = math.hypot(m_ned[0], m_ned[1])
            if h > 1e-3:
                alpha = wrap_pi(math.atan2(m_ned[1], m_ned[0]) - self._declination)
                mag_yaw = wrap_pi(yaw - alpha)
                noise = (p.mag_noise_ut / h) ** 2
                mag_var = p.calibration_sigma_rad ** 2 + noise
                if self._learned_iron.learned:
                    # learning (or learned): the learned hard iron's uncertainty replaces the calibration's
                    # hard-iron error; what a hard iron cannot explain stays
                    floor = learned_floor_var_rad2(p, h * h)
                    mag_var = floor + noise + self._iron.heading_variance(c_bn, m_ned)
                    averaged = floor - slow_floor_var_rad2(p, h * h, self.monitor.reentry_s)
        return mag_yaw, mag_var, noise, averaged

    def _magnetometer_trust_var(self, mag_var: float, noise: float, field: np.ndarray | None) -> float:
        """The magnetometer heading's slowly varying error variance that the heading state and the end of the iron
        learning are judged on, rad²: the calibration's; with a learned iron, what the iron leaves at the worst
        heading of a level vehicle (IronLearner.level_heading_variance) plus the floor of what a learned iron
        cannot explain, at the WMM horizontal field, as much of it as is left over the monitor's re-entry window
        (slow_floor.py: an error correlated over `iron_tau_s`, as the learner and the kernel take it). Not
        `mag_var` less its noise (what the kernel fuses, and what the magnetometer's re-entry and tilt trust read, at
        this attitude, their floor over the same window): that projects the iron's covariance on
        the heading the vehicle points at, so a half-learned iron read as learned on one leg and not on the next,
        stopping and restarting the learning and flipping the published state MAGNETOMETER ↔ LEARNING each time
        the boat turned (docs/gnss.md "Heading state"). This one only falls while learning."""
        if not self._learned_iron.learned or field is None or not math.isfinite(mag_var):
            return mag_var - noise if math.isfinite(mag_var) else math.nan
        h2 = float(field[0] ** 2 + field[1] ** 2)
        return slow_floor_var_rad2(self.params, h2, self.monitor.reentry_s) \
            + self._iron.level_heading_variance(field)

    def _tilt_heading_var(self) -> float:
        """The variance the filter's tilt uncertainty gives the magnetometer heading, rad²: a tilt about the
        horizontal axis across the field turns the heading of the field's horizontal part by tan(dip) as much
        (the larger tilt variance of the two, at the WMM dip). For the step test (mag_step.py); NaN without the
        WMM field (no test)."""
        field = self.field_ned
        if field is None:
            return math.nan
        h2 = float(field[0] ** 2 + field[1] ** 2)
        if h2 <= 0.0:
            return math.nan
        tilt_var = float(max(self._P[core.E_TILT_N, core.E_TILT_N], self._P[core.E_TILT_E, core.E_TILT_E]))
        return tilt_var * float(field[2]) ** 2 / h2

    def gnss_yaw(self) -> tuple[float, float, bool]:
        """The GNSS yaw bank's yaw, its variance (rad²) and whether it is valid: (NaN, inf, False) without the
        bank (gnss_yaw off) or before it has a finite yaw. While the lever-arm check finds the arm in use wrong,
        the bank takes the velocities through the arm it found (LeverArmFit.bank_arm, set in InsGnssFusion.fuse), not through
        the wrong one (docs/gnss.md "The lever-arm check")."""
        if self.params.gnss_yaw:
            y, sg, valid, _ = self._gsf_output(self._gsf_arr)
            if math.isfinite(y) and math.isfinite(sg):
                return float(y), float(sg) ** 2, bool(valid)
        return math.nan, math.inf, False

    def _monitor_decision(self, t_s: float, yaw: float, yaw_var: float, mag_yaw: float, mag_var: float,
                          slow_var: float, trust_var: float, gsf_yaw: float, gsf_var: float,
                          gsf_valid: bool) -> MonitorDecision:
        """The heading monitor's check of the filter's yaw against the magnetometer's and the GNSS yaw's
        (HeadingMonitor.check; slow_var: the magnetometer heading's slowly varying variance at this attitude,
        its re-entry's), and what follows from it before any yaw reset: the biases a GNSS yaw agreeing
        with the heading confirms are kept (a reset goes back to them), a magnetometer just rejected makes the
        heading unconfirmed again, and its yaw variance floor is applied (with the warning)."""
        p = self.params
        P = self._P
        observable = heading_observable(yaw_var, self.confirmation.unconfirmed_sigma_rad,
                                        p.heading_observable_sigma_rad)
        att_var, tilt_var = (math.nan, math.nan) if self.field_ned is None else \
            attitude_heading_variances(P[core.E_TH:core.E_TH + 3, core.E_TH:core.E_TH + 3], self.field_ned)
        d = self.monitor.check(t_s, yaw, yaw_var, mag_yaw, mag_var, gsf_yaw, gsf_var, gsf_valid, observable,
                                float(self._x["vel_gate"]["nis"]),
                                slow_var, trust_var,
                                self._tilt_heading_var(), float(P[core.E_BG + 2, core.E_BG + 2]),
                                p.gyro_noise_rad_s_sqrt_hz, att_var, tilt_var)
        f = monitor_follow_up(d, yaw_rad=yaw, yaw_var_rad2=yaw_var, gsf_yaw_rad=gsf_yaw, gsf_var_rad2=gsf_var,
                              gsf_valid=gsf_valid, gate_sigma=self.monitor.gate_sigma,
                              lowpassed_velocity_nis=self.monitor.lowpassed_velocity_nis,
                              reset_velocity_nis=self.monitor.reset_velocity_nis,
                              accel_bias_gsf_sigma_rad=p.accel_bias_gsf_sigma_rad,
                              filter_yaw_var_rad2=float(P[core.E_YAW, core.E_YAW]))
        if f.keep_confirmed_biases:
            self.confirmation.keep_confirmed_biases(self._x["gyro_bias_rad_s"], self._x["accel_bias_m_s2"])
        if f.bank_takes_filter_bias:
            self._x["bank_gyro_bias_rad_s"] = self._x["gyro_bias_rad_s"]
        if f.rejected:
            self._iron_before_rejection = self._learned_iron.learned
            self._learned_iron.release_offset()     # the iron may have changed: its offset is learned again
            self.confirmation.magnetometer_rejected()
            # what the magnetometer taught the gyro bias since the last confirmation goes with it: a wrong
            # magnetometer's heading error rate, which the filter would otherwise keep integrating as GNSS-only.
            # The value only: widening its variance too let the GNSS-only heading wander after an iron change
            # (docs/estimator.md, "Known limits: ins on level turns")
            self._x["gyro_bias_rad_s"] = self.confirmation.confirmed_gyro_bias
        if f.raise_yaw_var_to_rad2 is not None:
            P[core.E_YAW, core.E_YAW] = f.raise_yaw_var_to_rad2
            self.heading_interventions += 1
            if math.isfinite(d.mag_step_rad):
                log.warning("ins: magnetometer heading stepped by %+.1f° while the gyro saw no turn: iron changed; "
                            "magnetometer rejected", math.degrees(d.mag_step_rad))
            else:
                # the daemon's and replay's wording: a calibration that states its heading error was wrong (or the
                # iron moved since it); with none, or one of unknown quality, that is the reason itself
                stated = calibration_states_error(self.params.mag_calibration_sigma_rad)
                why = ("calibration wrong or iron changed" if stated
                       else "no magnetometer calibration stating its heading error")
                log.warning("ins: magnetometer disagrees with the GNSS-held heading by %.1f°: %s; magnetometer "
                            "rejected", math.degrees(self.monitor.rejection_disagreement_rad), why)
        return d

    def _reset_or_confirm_yaw(self, t_s: float, d: MonitorDecision, yaw: float, gsf_yaw: float, gsf_var: float,
                              gsf_valid: bool) -> float | None:
        """At most one of: the monitor's emergency yaw reset, the alignment to the first valid GNSS yaw
        (HeadingConfirmation.alignment_due), or, while the heading is held unconfirmed, its confirmation by a GNSS
        yaw that agrees with it. Returns the yaw a reset turned the attitude (about down) to, None without one."""
        c = self.confirmation
        if self._rerun_first_gnss_yaw and gsf_valid:
            # a start run again under the bank's yaw carried back (`start_rerun`): its first valid GNSS yaw is where
            # the run before aligned. The yaw it kept through the start was as wide as the bank's at its validity
            # limit, and the GNSS acceleration projected through it levelled the tilt, whose linearised variance
            # shrank faster than its error: restarted as a kept yaw's without a magnetometer
            # (`floor_yaw_sigma_without_magnetometer`). A bias-from-rotation window started before took that tilt's
            # variance for its start attitude: it starts again, as at the alignment the run before did
            self._rerun_first_gnss_yaw = False
            self._resets.restart_horizontal_accel_bias(self.params, self.confirmation.startup_accel_bias)
            self._resets.relevel(self.params, self.params.nav_init_sigma_tilt_rad)
            self._mag_rotation.restart()     # its start attitude: the tilt just re-levelled
        if d.reset_yaw_to_rad is not None:
            self.reset_yaw(d.reset_yaw_to_rad - yaw, d.reset_yaw_var_rad2)
            return d.reset_yaw_to_rad
        if c.alignment_due(yaw, gsf_yaw, gsf_var, gsf_valid):
            self._align_yaw_to_gnss(t_s, gsf_yaw - yaw, gsf_var)
            return gsf_yaw
        if not c.heading_confirmed and gsf_valid and (c.calibration_untrusted or self.monitor.mag_rejected):
            self._confirm_heading(yaw, gsf_yaw, gsf_var)
        return None

    def _align_yaw_to_gnss(self, t_s: float, dyaw_rad: float, gsf_var: float) -> None:
        """The planned first alignment of the yaw to the GNSS yaw (yaw_align_to_gnss_yaw). With the magnetometer
        rejected by now, what the start learned was learned against a heading found wrong: the filter may run its
        start again under this yaw (`rerun_due`, start_rerun.py)."""
        if self.monitor.mag_rejected and self.params.start_rerun_max_s > 0.0:    # off: nothing is kept to run again
            gsf_yaw = wrap_pi(float(quat_to_euler(self._x["q"])[2]) + dyaw_rad)
            self.rerun_due = (gsf_yaw, gsf_var, float(self._x["t_last_s"]), float(self._x["lat_rad"]))
        self.confirmation.aligned()         # the biases a reset goes back to: the start-up ones
        self.monitor.yaw_was_reset(t_s)     # an emergency reset keeps its spacing from this one
        self.reset_yaw(dyaw_rad, gsf_var, alignment=True)
        # the specific force the tilt was levelled against, turned by the alignment's yaw step: its horizontal part
        # across the new heading, |f_h|·|sin Δψ|, was taken as a lean of the tilt (a car accelerating away leans it
        # by degrees, a slow boat hardly at all)
        f = self._x["acc_ned_lp_m_s2"]
        across = math.hypot(float(f[0]), float(f[1])) * abs(math.sin(wrap_pi(dyaw_rad)))
        self._resets.relevel(self.params, math.atan2(across, abs(float(f[2]))))

    def start_rerun(self, before: "HeadingSupervision.Counts") -> None:
        """The filter starts again from its first sample with the GNSS yaw bank's yaw carried back to it
        (start_rerun.py): the magnetometer stands rejected from the start, as the run before rejected it (no yaw
        floor: the yaw's variance is the carried-back bank's), the yaw counts as aligned to the GNSS yaw (the
        bank confirms it with the looser figure, and it is not aligned again), and the counts and the monitor's
        resets and rejection go on from the run before."""
        m = self.monitor
        self._iron_before_rejection = self._learned_iron.learned
        self._learned_iron.release_offset()
        m.mag_rejected = True
        m.rejections = before.rejections
        m.rejection_disagreement_rad = before.rejection_disagreement_rad
        m.max_disagreement_rad = before.max_disagreement_rad
        m.resets = before.monitor_resets
        m.last_reset_t_s = before.last_reset_t_s
        self.confirmation.aligned_before_start()
        self._rerun_first_gnss_yaw = True
        self._par["mag_use"] = 0.0
        self.yaw_resets = before.yaw_resets
        self.gnss_yaw_alignments = before.gnss_yaw_alignments
        self.heading_interventions = before.heading_interventions

    class Counts(NamedTuple):
        """What a start run again carries over from the run before (`counts`, `start_rerun`)."""

        rejections: int
        rejection_disagreement_rad: float
        max_disagreement_rad: float
        monitor_resets: int
        last_reset_t_s: float
        yaw_resets: int
        gnss_yaw_alignments: int
        heading_interventions: int

    def counts(self) -> "HeadingSupervision.Counts":
        m = self.monitor
        return self.Counts(m.rejections, m.rejection_disagreement_rad, m.max_disagreement_rad, m.resets,
                           m.last_reset_t_s, self.yaw_resets, self.gnss_yaw_alignments, self.heading_interventions)

    def _confirm_heading(self, yaw: float, gsf_yaw: float, gsf_var: float) -> None:
        """A GNSS yaw that agrees with the held heading confirms it (HeadingConfirmation.confirm); otherwise the
        yaw variance is raised to at least the GNSS yaw's."""
        P = self._P
        if self.confirmation.confirm(yaw, gsf_yaw, gsf_var, P[core.E_YAW, core.E_YAW]):
            P[core.E_YAW, core.E_YAW] = gsf_var

    def _set_magnetometer_use(self, d: MonitorDecision, mag_var: float, noise: float, trust_var: float,
                              slow_var: float) -> None:
        """What the kernel does with the magnetometer after the check (magnetometer_use.py decides it from what the
        check left), written into the kernel's parameters; and the variances the next check's trust (slow_var: the
        slowly varying variance at this attitude, the learned floor over the trust window, slow_floor.py) and the
        heading state use."""
        iron = IronState(learning=self.monitor.learning, updates=self._iron.updates,
                         restored=self._learned_iron.restored, before_rejection=self._iron_before_rejection,
                         offset_held=self._iron.offset_held)
        u = magnetometer_use(self.params, monitor_use=d.mag_use, trusted_sigma_rad=self.monitor.trusted_sigma_rad,
                             slow_var_rad2=self._mag_var, mag_var_rad2=mag_var, noise_rad2=noise,
                             trust_var_rad2=trust_var, calibration_untrusted=self._calibration_untrusted, iron=iron,
                             learned_floor_var_rad2=self._learned_floor_var_here,
                             heading_rate_rad_s=self._heading_rate_rad_s,
                             yaw_var_rad2=float(self._P[core.E_YAW, core.E_YAW]))
        self._par["mag_use"] = u.mag_use
        self._par["mag_moves_tilt"] = u.mag_moves_tilt
        if math.isfinite(mag_var):
            self._mag_var = slow_var      # the slowly varying part at this attitude: what trust uses
            self._mag_trust_var = trust_var      # what the heading state uses (_magnetometer_trust_var)
        if u.mag_bias_var_rad2 is not None:
            self._par["mag_bias_var_rad2"] = u.mag_bias_var_rad2
            self._par["mag_bias_tau_s"] = u.mag_bias_tau_s

    def _learned_floor_var_here(self) -> float | None:
        """The learned magnetometer's floor over the trust window (slow_floor.slow_floor_var_rad2) at the WMM
        horizontal field at the filter's position (inf where it has none, None without the WMM field), rad²: what
        `never_trusted_here` judges, as the trust tests do."""
        field = self.field_ned
        if field is None:
            return None
        h2 = float(field[0] ** 2 + field[1] ** 2)
        return slow_floor_var_rad2(self.params, h2, self.monitor.reentry_s) if h2 > 0.0 else math.inf

    def _heading_rate_rad_s(self) -> float:
        """|rate about down| of the last gyro sample, bias removed, rad/s."""
        x = self._x
        c_bn = np.asarray(quat_to_dcm(x["q"]), dtype=float)
        return abs(float(c_bn[2] @ (x["gyro_last_rad_s"] - x["gyro_bias_rad_s"])))

    def _learn_iron(self, t_s: float, c_bn: np.ndarray, field: np.ndarray | None) -> bool:
        """One step of the iron learning (IronLearner) against the WMM field at the filter's position, with the
        attitude c_bn and its covariance; the kernel then removes the learned iron (`apply_learned_iron`, which
        sets the harmonics' source too). Returns whether it learned (False: no WMM field)."""
        p = self.params
        if field is None:
            return False
        att = slice(core.E_TH, core.E_TH + 3)
        self._learned_iron.learn(t_s, self._x["mag_last_ut"], c_bn, field, self._P[att, att],
                                 self._P[core.E_YAW, core.E_YAW], p.iron_unmodelled_ut, p.iron_tau_s,
                                 magnetometer_fused=self._par["mag_use"] > 0.5)
        self.apply_learned_iron()
        return True

    def _publish_heading_checks(self, t_s: float, yaw_rad: float, gsf_yaw: float, gsf_var: float,
                                gsf_valid: bool) -> None:
        """What the checks publish: the yaw σ's floor while the heading is unconfirmed
        (HeadingConfirmation.unconfirmed_yaw_sigma at the yaw after any reset), the integrity figures and the
        heading state."""
        c = self.confirmation
        c.update_sigma_confirmation(yaw_rad, gsf_yaw, gsf_var, gsf_valid, self._P[core.E_YAW, core.E_YAW])
        c.unconfirmed_sigma_rad = c.unconfirmed_yaw_sigma(yaw_rad, gsf_yaw, gsf_var)
        sig = math.sqrt(max(self._P[core.E_YAW, core.E_YAW], 0.0))
        if c.unconfirmed_sigma_rad > sig:
            sig = c.unconfirmed_sigma_rad
        self.publication.publish(t_s, self.monitor, sig, gsf_yaw, gsf_var, gsf_valid, self._mag_trust_var,
                                  float(self._x["mag"]["since_update_s"]), self._iron.offset_ut,
                                  self._iron.sigma_ut, self._lever_arm_fit.heading_bent)

    def floor_yaw_sigma_without_magnetometer(self, t_s: float) -> None:
        """No magnetometer (mag_enabled off): the yaw comes from the GNSS velocity alone, pulled in from an unknown
        start (1σ π) through linearised updates, whose variance shrinks faster than the error on a boat's weak
        accelerations (docs/estimator.md "Known limits: ins on level turns"), and which, tens of degrees off, reject
        the velocities that would pull it in: if the first valid GNSS yaw disagrees with it, it is set to that yaw
        (HeadingConfirmation.alignment_due). The heading checks do not run (they weigh a magnetometer), so nothing
        ever confirms this yaw: its published 1σ is at least the GNSS yaw bank's plus the distance to it, as an
        unconfirmed heading's (HeadingConfirmation.unconfirmed_yaw_sigma), at every fused fix."""
        if not (self.params.gnss_yaw and self.params.heading_monitor):
            return
        yaw = float(quat_to_euler(self._x["q"])[2])
        gsf_yaw, gsf_var, gsf_valid = self.gnss_yaw()
        c = self.confirmation
        if c.alignment_due(yaw, gsf_yaw, gsf_var, gsf_valid):
            self._align_yaw_to_gnss(t_s, gsf_yaw - yaw, gsf_var)
            yaw = gsf_yaw
        elif c.first_gnss_yaw_keeps_yaw(gsf_valid):
            # the yaw is kept, but the pull-in that brought it inside the bank's 3σ ran through yaws tens of
            # degrees off: the horizontal bias and the tilt it taught are restarted as an alignment restarts them
            self._resets.restart_horizontal_accel_bias(self.params, c.startup_accel_bias)
            self._resets.relevel(self.params, self.params.nav_init_sigma_tilt_rad)
        c.gnss_yaw_seen(gsf_valid)
        c.unconfirmed_sigma_rad = gnss_yaw_floor(yaw, gsf_yaw, gsf_var)

    @property
    def _calibration_untrusted(self) -> bool:
        """The magnetometer calibration in force predicts a heading error above what the heading monitor trusts
        (HeadingConfirmation.calibration_untrusted)."""
        return self.confirmation.calibration_untrusted

    @property
    def _heading_checks_run(self) -> bool:
        """The heading checks (`check`) run at the fused fixes and can confirm a heading: the GNSS yaw, the monitor
        and the magnetometer are on."""
        p = self.params
        return p.gnss_yaw and p.heading_monitor and p.mag_enabled

    def set_accel_bias_learning(self) -> None:
        """With accel_bias_needs_heading, the horizontal accelerometer bias learns from GNSS only while the heading
        is known: a trusted magnetometer, or a GNSS yaw within `accel_bias_gsf_sigma_rad` has agreed with the
        heading since the magnetometer was last rejected (ins_core._gated_update says why). Without the heading
        checks (no GNSS yaw, monitor or magnetometer) there is nothing to confirm with: it always learns."""
        p = self.params
        held = self.confirmation.bias_learning_held(p.accel_bias_needs_heading, self.monitor.mag_rejected)
        self._par["accel_bias_learn"] = 0.0 if held else 1.0

    def reset_yaw(self, dyaw_rad: float, var_rad2: float, alignment: bool = False) -> None:
        """Turn the attitude (and its history) about down by dyaw with yaw variance var, the biases back to the last
        confirmed ones (YawReset.turn); then what the wrong yaw had started begins again: the velocity from the
        last fix, the magnetometer's error states from their priors, the bias-from-rotation window. Counted,
        flagged and logged."""
        c = self.confirmation
        dyaw = self._resets.turn(self.params, dyaw_rad, var_rad2, c.confirmed_gyro_bias, c.confirmed_accel_bias)
        self._fusion.reset_velocity_to_fix()
        # the calibration's error estimated against the heading just found wrong starts again from its prior
        self.restart_calibration_error_states()
        self._mag_rotation.restart()      # its window started from the old heading
        self.yaw_resets += 1
        self._lever_arm_fit.heading_reset()    # another attitude error from here on (lever_arm_fit.py)
        self.heading_interventions += 1
        self._on_yaw_reset()
        if alignment:     # the planned first alignment (yaw_align_to_gnss_yaw), not a heading found wrong
            self.gnss_yaw_alignments += 1
            log.info("ins: heading aligned to the GNSS yaw by %.1f° (reset %d)", math.degrees(dyaw), self.yaw_resets)
        else:
            log.warning("ins: heading reset to the GNSS yaw by %.1f° (reset %d)%s", math.degrees(dyaw),
                        self.yaw_resets, " (the antenna arm found wrong: the heading stays unknown)"
                        if self._lever_arm_fit.heading_bent else "")


def _finite3(v: np.ndarray) -> bool:
    """Every element of the 3-vector v finite: np.all(np.isfinite(v)) for a float64 3-vector, in Python floats
    (the ufunc and the reduction cost many times the test, per fix)."""
    a, b, c = v.tolist()
    return math.isfinite(a) and math.isfinite(b) and math.isfinite(c)
