"""The hard iron a wrong calibration left, learned from the circle the levelled field sweeps in turns (no GNSS).

field_circle.py finds the calibration wrong when the circle's centre is off beyond the fit's uncertainty. Its
centre is the horizontal part, in the levelled frame, of the hard iron the calibration did not remove: subtracting
it from the field corrects the heading (W. Premerlani, "Automatic nulling of magnetometer offsets", DIY Drones
2010: offsets rotate with the body while the Earth field does not, so rotation separates them; ArduPilot's old
COMPASS_LEARN=1 nulled offsets that way without GNSS). This part holds that correction:

* it starts when the check first finds the calibration wrong (`learn`); from then on its target is the fit's
  centre at every judgement that covered the turns, or, after the iron moved and before the restarted fit covers
  them again, the centre on the old radius (field_circle_change.py; its σ as wide as the fields leave it) (the
  fit goes on with the fields as the calibration gives them;
  the check judges the centre minus the correction applied, so a corrected field reads consistent, and an iron
  that moves again is found again);
* the applied correction moves towards the target at a heading rate of `rate_rad_s` (estimator/slewed_yaw.YawSlew,
  the rule every slewed heading in ahrsd follows): the filter's heading follows the corrected field at no more
  than that rate, so no published step;
* it is a body-fixed vector, as a hard iron is: the centre's x, y as the body's x, y (exact for a level vehicle;
  on one that banks the centre is the iron seen through its mean tilt), and 0 along the body's z (the
  calibration's): the fit is planar and a level vehicle never shows the vertical part. Turned through the filter's
  current tilt instead (horizontal in the levelled frame at every sample), the correction would change as the
  vehicle banks while the iron does not: on the simulated plane the heading was worse and beyond its 3σ
  (docs/estimator.md);
* the soft iron (the ellipse) is not learned: the check keeps judging it and widening σ by it;
* the published σ covers what is left (`heading_var_rad2`): the heading error of the centre still not applied or
  not yet taken up by the filter (`settle_s`), as a sinusoid's RMS like the check's own, plus the fit's own
  uncertainty of the centre, σ_c/H, as a consider term where calibration_heading.py puts the calibration's figure;
* it can start from a correction learned in an earlier run on the same calibration (`restore`, the daemon's
  learned-iron store): applied from the first sample, with the σ that run knew of it (`sigma_ut`: the fit's σ_c
  and the tilt term, in µT) over the horizontal field measured now (`see_horizontal_field`), until the circle
  of this run judges it (the first covered judgement replaces the target and its σ, as in the first run).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .field_circle import hard_iron_heading_var_rad2
from .slewed_yaw import YawSlew


@dataclass(frozen=True)
class FieldCircleCorrectionParams:
    """SI units, angles rad, fields µT."""

    rate_rad_s: float = math.radians(1.0)
    """The heading rate at which the correction is moved in (its size over the circle's radius per second)."""
    settle_s: float = 30.0
    """The filter's heading takes up a change of the field as a first-order lag of about this time constant, which
    the σ counts until it has passed (mekf's default tuning: docs/estimator.md)."""


class FieldCircleCorrection:
    """`learn(result, claimed_var_rad2, t_s)` at each judgement of the check; `advance(dt_s, yaw_sigma_rad)` at each
    field it takes; `body_ut` the correction to subtract from the body-frame field (None: none learned);
    `applied_ut` its x, y, which the check judges the centre against; `heading_var_rad2()` for σ."""

    def __init__(self, params: FieldCircleCorrectionParams | None = None):
        self.params = params or FieldCircleCorrectionParams()
        self._slew = YawSlew(self.params.rate_rad_s)
        self.reset()

    def reset(self) -> None:
        self.active = False
        self.target_ut = np.zeros(2)        # the fit's centre, levelled frame (x fwd, y right)
        self.applied_ut = np.zeros(2)       # what is subtracted now
        self.settled_ut = np.zeros(2)       # what the filter's heading has taken up (a lag of settle_s)
        self.centre_sigma_ut = 0.0
        self.tilt_rms_rad = 0.0
        self.vertical_ut = 0.0              # the vertical iron an iron's move left (not removed: field_circle.py)
        self.radius_ut = math.nan
        self.started_t_s = math.nan
        self.restored = False               # started from an earlier run's correction, not yet judged in this one
        self.body_ut: np.ndarray | None = None

    def restore(self, body_ut, sigma_ut: float) -> None:
        """Start from a correction learned in an earlier run on the same calibration: the body's x, y applied at
        once (the filter starts on the corrected field, so nothing is left to take up), with `sigma_ut` (that
        run's `sigma_ut()`) as the centre's uncertainty; its heading σ waits for the horizontal field
        (`see_horizontal_field`). ValueError when not finite, or with a vertical part (the turns learn none)."""
        b = np.asarray(body_ut, dtype=float).reshape(3)
        sigma_ut = float(sigma_ut)
        if not (np.all(np.isfinite(b)) and math.isfinite(sigma_ut) and sigma_ut >= 0.0) or b[2] != 0.0:
            raise ValueError(f"not a correction learned in turns: {b.tolist()} ± {sigma_ut} µT")
        self.reset()
        if not np.any(b != 0.0):
            return                          # nothing was learned
        self.active = self.restored = True
        self.target_ut = b[:2].copy()
        self.applied_ut = b[:2].copy()
        self.settled_ut = b[:2].copy()
        self.centre_sigma_ut = sigma_ut
        self.body_ut = b.copy()

    def see_horizontal_field(self, horizontal_ut: float) -> None:
        """The horizontal field the corrected field shows now (levelled), for the heading σ of a restored
        correction until the circle's own radius is known."""
        if self.restored and not math.isfinite(self.radius_ut) and horizontal_ut > 0.0:
            self.radius_ut = float(horizontal_ut)

    def sigma_ut(self) -> float:
        """What is known of the target, as a horizontal field error (µT, 1σ): the fit's σ_c and the iron seen
        through the tilt (heading_var_rad2's terms times H) — what a later run may claim of it."""
        seen_through_tilt_ut = math.hypot(*self.target_ut) * (1.0 - math.cos(self.tilt_rms_rad))
        vertical_through_tilt_ut = self.vertical_ut * math.sin(self.tilt_rms_rad)
        return math.hypot(self.centre_sigma_ut, seen_through_tilt_ut, vertical_through_tilt_ut)

    def learn(self, result, claimed_var_rad2: float, t_s: float) -> None:
        """A new judgement of the circle check (field_circle.FieldCircleResult)."""
        if not self.active:
            if not result.finds_wrong(claimed_var_rad2):
                return
            self.active = True
            self.started_t_s = t_s
        if ((result.covered or result.moved) and math.isfinite(result.radius_ut)
                and math.isfinite(result.centre_sigma_ut)):
            self.restored = False
            self.target_ut = np.array(result.centre_ut, dtype=float)
            self.radius_ut = result.radius_ut
            self.centre_sigma_ut = result.centre_sigma_ut
            self.tilt_rms_rad = result.tilt_rms_rad if math.isfinite(result.tilt_rms_rad) else 0.0
            self.vertical_ut = result.vertical_ut

    def advance(self, dt_s: float, yaw_sigma_rad: float) -> None:
        """Move the applied correction towards the target over dt_s (yaw_sigma_rad: the filter's, for the slew's
        rate rule)."""
        if not self.active or not dt_s > 0.0:
            return
        d = self.target_ut - self.applied_ut
        size = math.hypot(d[0], d[1])
        if size > 0.0:
            move, arrived = self._slew.step(size / self.radius_ut, yaw_sigma_rad, dt_s)
            self.applied_ut = self.target_ut.copy() if arrived else self.applied_ut + d * (abs(move) * self.radius_ut
                                                                                           / size)
        self.settled_ut += (self.applied_ut - self.settled_ut) * (-math.expm1(-dt_s / self.params.settle_s))
        self.body_ut = np.array([self.applied_ut[0], self.applied_ut[1], 0.0])

    def heading_var_rad2(self) -> float:
        """The heading variance still left: the centre not yet applied or taken up, as a sinusoid's RMS
        (amplitude asin(|c − applied|/H)), plus the fit's uncertainty of the centre over H, plus how far the
        levelled centre can be from the body-fixed iron on a vehicle that tilts: the iron seen through a tilt τ
        is shortened by up to |c|·(1 − cos τ) (τ the tilt's RMS over the fit's window), a bias the fit's
        residuals do not show."""
        if not self.active:
            return 0.0
        if not math.isfinite(self.radius_ut):
            return math.pi ** 2             # a restored correction before any field: nothing claimed
        left = max(math.hypot(*(self.target_ut - self.applied_ut)), math.hypot(*(self.target_ut - self.settled_ut)))
        return hard_iron_heading_var_rad2(left, self.radius_ut) + self.sigma_ut() ** 2 / self.radius_ut ** 2

    def applied_heading_var_rad2(self) -> float:
        """The heading variance the applied correction removes (the sinusoid a hard iron of its size leaves), for
        σ when it is forgotten; π² before the horizontal field is known."""
        if not math.isfinite(self.radius_ut):
            return math.pi ** 2
        return hard_iron_heading_var_rad2(math.hypot(*self.applied_ut), self.radius_ut)
