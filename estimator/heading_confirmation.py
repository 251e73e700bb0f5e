"""What `ins` holds about its heading between the heading checks: whether a GNSS yaw has confirmed it, the yaw set
once to the first valid GNSS yaw, the floor of the published yaw σ while nothing has confirmed it, and the biases a
yaw reset goes back to.

The heading checks (ins.Ins._check_heading, at the fused fixes) weigh the filter's yaw against the magnetometer's
and the GNSS yaw bank's (estimator/gsf_yaw.py) through the heading monitor (heading_monitor.py); this part is told
what they saw and answers what follows for the heading: is the alignment to the GNSS yaw due, does a GNSS yaw
confirm the held heading, what 1σ may be published for it. It owns its flags and reads nothing of the filter: the
filter's yaw, its variance and the bank's output are arguments; the figures it judges with are its constructor's.
What the answers do to the filter's state (a yaw reset, a raised variance) stays with the filter.

Why each rule is as it is: docs/estimator.md ("Alignment", "A wrong heading must not teach the accelerometer
bias", "Magnetometer-free GNSS yaw") and docs/gnss.md ("Heading state").
"""

from __future__ import annotations

import math

import numpy as np

from .heading_monitor import wrap_pi


class HeadingConfirmation:
    """The confirmation state of one run of the filter (built again when the heading checks start again).

    align_to_gnss_yaw: InsParams.yaw_align_to_gnss_yaw; mag_enabled: InsParams.mag_enabled; checks_run: the heading
    checks run at the fused fixes (the GNSS yaw bank, the monitor and the magnetometer on); heading_confirm_sigma_rad
    and bias_confirm_sigma_rad: the GNSS yaw's 1σ below which it confirms the heading (InsParams.
    heading_confirm_gsf_sigma_rad) and the accelerometer bias (InsParams.accel_bias_gsf_sigma_rad); gate_sigma: the
    monitor's gate (HeadingMonitor.gate_sigma); calibration_sigma_rad and trusted_sigma_rad: the magnetometer
    calibration's predicted heading error (InsParams.calibration_sigma_rad) and what the monitor trusts
    (HeadingMonitor.trusted_sigma_rad), told again by `set_calibration` when a new calibration is in force."""

    def __init__(self, *, align_to_gnss_yaw: bool, mag_enabled: bool, checks_run: bool,
                 heading_confirm_sigma_rad: float, bias_confirm_sigma_rad: float, gate_sigma: float,
                 calibration_sigma_rad: float, trusted_sigma_rad: float):
        self._align_to_gnss_yaw = align_to_gnss_yaw
        self._mag_enabled = mag_enabled
        self.checks_run = checks_run
        self._heading_confirm_sigma_rad = heading_confirm_sigma_rad
        self._bias_confirm_sigma_rad = bias_confirm_sigma_rad
        self._gate_sigma = gate_sigma
        self._calibration_sigma_rad = calibration_sigma_rad
        self._trusted_sigma_rad = trusted_sigma_rad
        self.heading_confirmed = False    # by a GNSS yaw within heading_confirm_sigma_rad
        self.bias_heading_confirmed = False   # by a GNSS yaw within bias_confirm_sigma_rad
        self.gnss_yaw_aligned = False     # the yaw was set to the first valid GNSS yaw (align_to_gnss_yaw)
        self.gnss_yaw_valid_seen = False  # a GNSS yaw was valid (without a magnetometer, the alignment's chance)
        self.sigma_confirmed = False      # the published σ's floor is lifted (`update_sigma_confirmation`)
        # the published yaw σ's floor until a GNSS yaw confirms the heading (aided only; updated at every check)
        self.unconfirmed_sigma_rad = self.unconfirmed_yaw_sigma(0.0, math.nan, math.nan)
        # the biases a yaw reset goes back to: the last a GNSS yaw confirmed, and the start-up ones (set at the
        # filter's start, `start_biases`)
        self.confirmed_gyro_bias: np.ndarray | None = None
        self.confirmed_accel_bias: np.ndarray | None = None
        self.startup_gyro_bias: np.ndarray | None = None
        self.startup_accel_bias: np.ndarray | None = None

    def set_calibration(self, calibration_sigma_rad: float, trusted_sigma_rad: float) -> None:
        """A new magnetometer calibration is in force (its predicted heading error, what the monitor trusts)."""
        self._calibration_sigma_rad = calibration_sigma_rad
        self._trusted_sigma_rad = trusted_sigma_rad

    @property
    def calibration_untrusted(self) -> bool:
        """The magnetometer calibration in force predicts a heading error above what the heading monitor trusts
        (an unknown calibration counts as the uncalibrated figure, `InsParams.calibration_sigma_rad`)."""
        return self._calibration_sigma_rad > self._trusted_sigma_rad

    # ----------------------------------------------------------------------- the biases a reset goes back to
    def start_biases(self, gyro_bias: np.ndarray, accel_bias: np.ndarray) -> None:
        """The filter starts from these biases: the last confirmed ones and the start-up ones (copies)."""
        self.confirmed_gyro_bias = gyro_bias.copy()
        self.confirmed_accel_bias = accel_bias.copy()
        self.startup_gyro_bias = gyro_bias.copy()     # what the GNSS-yaw alignment goes back to
        self.startup_accel_bias = accel_bias.copy()

    def keep_confirmed_biases(self, gyro_bias: np.ndarray, accel_bias: np.ndarray) -> None:
        """A GNSS yaw agreed with the filter's heading: its biases were learned with a right heading (copies)."""
        self.confirmed_gyro_bias = gyro_bias.copy()
        self.confirmed_accel_bias = accel_bias.copy()

    # ----------------------------------------------------------------------- what the checks tell it
    def magnetometer_rejected(self) -> None:
        """The magnetometer was just rejected: the heading it held is unconfirmed again (`confirm`)."""
        self.heading_confirmed = False
        self.bias_heading_confirmed = False
        self.sigma_confirmed = False

    def aligned(self) -> None:
        """The yaw is being set to the first valid GNSS yaw (`alignment_due`). Nothing confirmed the heading before
        it, so the biases go back to their start-up values: learned against an uncalibrated magnetometer, whose
        heading error changes as the vehicle turns (vehicle iron), the vertical gyro bias has taken up that error's
        rate, and the filter's agreement check, with the bank's σ near its validity limit, would keep them as
        "confirmed" (docs/estimator.md, "Alignment")."""
        self.gnss_yaw_aligned = True
        self.confirmed_gyro_bias = self.startup_gyro_bias.copy()
        self.confirmed_accel_bias = self.startup_accel_bias.copy()

    def aligned_before_start(self) -> None:
        """The filter starts again from its first sample with its yaw set from the GNSS yaw (start_rerun.py): it
        counts as aligned (a GNSS yaw confirms it with the looser figure, and it is not aligned again); the biases
        a reset goes back to stay the start-up ones."""
        self.gnss_yaw_aligned = True

    def arm_adopted(self) -> None:
        """The filter fuses at another antenna arm (lever_arm_fit.py): the heading the wrong arm bent is found
        again as at the start, unconfirmed, aligned to the GNSS yaw bank's once valid."""
        self.gnss_yaw_aligned = False
        self.gnss_yaw_valid_seen = False
        self.heading_confirmed = False
        self.bias_heading_confirmed = False
        self.sigma_confirmed = False

    def gnss_yaw_seen(self, gsf_valid: bool) -> None:
        """Without a magnetometer: a fused fix's GNSS yaw was (or was not) valid."""
        self.gnss_yaw_valid_seen = self.gnss_yaw_valid_seen or gsf_valid

    # ----------------------------------------------------------------------- what it answers
    def alignment_due(self, yaw_rad: float, gsf_yaw: float, gsf_var: float, gsf_valid: bool) -> bool:
        """Whether the yaw is set, once per run, to the valid GNSS yaw (ins.Ins._align_yaw_to_gnss), with or without
        the magnetometer (the one rule for both).
        With the magnetometer: at the first valid GNSS yaw, no trusted magnetometer calibration, the heading not
        yet confirmed: the filter's yaw came from the magnetometer (tens of degrees off with a strong iron) and was
        pulled in by the GNSS velocity through a linearised update, whose biases take up what the yaw error
        projects (docs/estimator.md "A wrong heading must not teach the accelerometer bias"). An emergency reset at
        the same fix (HeadingMonitor.check) does not count: the alignment follows at the next check, which resets
        the velocity and the biases once more after the first update with the new yaw (measured, docs/estimator.md).
        Without it (mag_enabled off): at the first valid GNSS yaw, if the filter's yaw lies outside its 3σ
        (the monitor's gate of the bank's σ alone: the filter's own variance, shrunk by the linearised
        pull-in faster than its error, would widen the gate for a yaw nothing has confirmed, as for
        `unconfirmed_yaw_sigma`). The filter's yaw and its biases came from the same GNSS velocities as the bank's;
        where the filter's is inside the bank's 3σ it is kept: setting it to the bank's would widen its variance to
        the bank's and send the biases back to their start-up values, and on a boat's weak accelerations the
        velocities then pull the yaw further off than it was. Outside it, the filter's linearised update has not
        pulled its yaw in from the unknown start, and a yaw tens of degrees off makes the gate reject the very
        velocities that would (a car accelerating away): it is set to the bank's, as PX4 EKF2 aligns its yaw to
        the EKF-GSF without a magnetometer heading. Only at the first valid one: without the heading checks nothing
        gives the bank the filter's gyro bias, so on a long run its yaw drifts while its σ shrinks, and it comes to
        "disagree" with a right yaw (docs/estimator.md "Without a magnetometer: the yaw set to a GNSS yaw that
        disagrees").
        The filter's reset sets the yaw to the GNSS yaw with its variance and gives the biases, learned against the
        wrong yaw, their start-up values back."""
        if not (self._align_to_gnss_yaw and gsf_valid and not self.gnss_yaw_aligned):
            return False
        if not self._mag_enabled:
            outside = wrap_pi(gsf_yaw - yaw_rad) ** 2 > self._gate_sigma ** 2 * gsf_var
            return outside and not self.gnss_yaw_valid_seen
        return not self.heading_confirmed and self.calibration_untrusted

    def first_gnss_yaw_keeps_yaw(self, gsf_valid: bool) -> bool:
        """Without a magnetometer: this is the first valid GNSS yaw, and the filter's yaw was inside its 3σ, so
        `alignment_due` kept it."""
        return (self._align_to_gnss_yaw and gsf_valid and not self.gnss_yaw_valid_seen
                and not self.gnss_yaw_aligned)

    def agrees(self, yaw_rad: float, gsf_yaw: float, gsf_var: float, yaw_var_rad2: float) -> bool:
        """The GNSS yaw is within the monitor's gate of the filter's yaw (variance yaw_var_rad2, now), with their
        joint variance."""
        return wrap_pi(gsf_yaw - yaw_rad) ** 2 <= self._gate_sigma ** 2 * (yaw_var_rad2 + gsf_var)

    def confirm(self, yaw_rad: float, gsf_yaw: float, gsf_var: float, yaw_var_rad2: float) -> bool:
        """A GNSS yaw that agrees with the held heading confirms it for the accelerometer bias (within
        `bias_confirm_sigma_rad`) and for the heading (within `heading_confirm_sigma_rad`, or the looser bias figure
        after the alignment). True when it does not confirm the heading and is wider than the filter's yaw
        variance: the filter raises its yaw variance to at least the GNSS yaw's."""
        agrees = self.agrees(yaw_rad, gsf_yaw, gsf_var, yaw_var_rad2)
        if agrees and gsf_var < self._bias_confirm_sigma_rad ** 2:
            self.bias_heading_confirmed = True
        # a yaw set to the GNSS yaw (not pulled in from tens of degrees) is confirmed by the looser GNSS yaw
        confirm_rad = self._bias_confirm_sigma_rad if self.gnss_yaw_aligned else self._heading_confirm_sigma_rad
        if agrees and gsf_var < confirm_rad ** 2:
            self.heading_confirmed = True
            self.bias_heading_confirmed = True
            return False
        return gsf_var > yaw_var_rad2

    def bias_learning_held(self, needs_heading: bool, mag_rejected: bool) -> bool:
        """With `needs_heading` (InsParams.accel_bias_needs_heading), the horizontal accelerometer bias learns from
        GNSS only while the heading is known: a trusted magnetometer, or a GNSS yaw within `bias_confirm_sigma_rad`
        has agreed with the heading since the magnetometer was last rejected (ins_core._gated_update says why).
        Without the heading checks there is nothing to confirm with: it always learns."""
        return needs_heading and self.checks_run and not self.bias_heading_confirmed and (
            self.calibration_untrusted or mag_rejected)

    def update_sigma_confirmation(self, yaw_rad: float, gsf_yaw: float, gsf_var: float, gsf_valid: bool,
                                  yaw_var_rad2: float) -> None:
        """Whether the published yaw σ's floor (`unconfirmed_yaw_sigma`) is lifted: once the filter has confirmed
        its heading (`confirm`), when a GNSS yaw within `heading_confirm_sigma_rad` agrees. The filter confirms a
        yaw set to a GNSS yaw (alignment, emergency reset) with the looser `bias_confirm_sigma_rad`, but that yaw
        is only as good as the bank that set and confirmed it (σ up to 10°), and the fixes pull it through the
        linearised update, whose variance shrinks faster than the error as a turn ends (docs/gnss.md).
        After a rejection the monitor widens the yaw variance (tens of degrees) and the looser GNSS yaw agrees
        with it whatever the yaw. In both cases the floor stays published until the 5° GNSS yaw agrees;
        the filter keeps its own decision."""
        if not self.heading_confirmed:
            self.sigma_confirmed = False
        elif not self.sigma_confirmed:
            self.sigma_confirmed = (gsf_valid and gsf_var < self._heading_confirm_sigma_rad ** 2
                                    and self.agrees(yaw_rad, gsf_yaw, gsf_var, yaw_var_rad2))

    def unconfirmed_yaw_sigma(self, yaw_rad: float, gsf_yaw: float, gsf_var: float) -> float:
        """Without a trusted magnetometer calibration, until a GNSS yaw has confirmed the heading: the filter's yaw
        came from a magnetometer that may be off by anything (or was just set to a GNSS yaw the next fixes may
        pull away), and the GNSS velocity pulling it through a linearised update shrinks its variance faster than
        its error. The honest 1σ is then at least the GNSS yaw bank's, which carries the spread of its
        hypotheses, plus the distance to it (π before the bank has a yaw; NaN: no floor). Published only: the
        filter keeps its own variance (raising it would make the linearised update pull harder)."""
        if not (self._align_to_gnss_yaw and self.checks_run) or self.sigma_confirmed \
                or not self.calibration_untrusted:
            return math.nan
        return gnss_yaw_floor(yaw_rad, gsf_yaw, gsf_var)


def gnss_yaw_floor(yaw_rad: float, gsf_yaw: float, gsf_var: float) -> float:
    """The smallest honest 1σ of a yaw the GNSS yaw bank has not confirmed: the bank's own (the spread of its
    hypotheses) plus the distance to it; π before the bank has a yaw."""
    if not (math.isfinite(gsf_yaw) and math.isfinite(gsf_var)):
        return math.pi
    return math.sqrt(gsf_var + wrap_pi(gsf_yaw - yaw_rad) ** 2)


__all__ = ["HeadingConfirmation", "gnss_yaw_floor"]
