"""A step of the magnetometer's heading error while the gyro says the vehicle did not turn: an iron change (a
battery, a winch, a load moved) seen at once, on a straight leg too.

The heading monitor's innovation is the magnetometer heading minus the filter's heading, and between checks the
filter's heading moves with the integrated gyro, good to hundredths of a degree over seconds. So a turn moves both
alike and leaves the innovation where it was; an iron that steps moves the magnetometer alone and steps the
innovation. Each single innovation may still be small against the magnetometer's stated noise (a 3° step against
a noise of 2° and a correlated calibration error inflated for its correlation time), but the mean over a few
seconds after, against the mean over the seconds before, is not: the two-window test for a change in the mean
(M. Basseville, I. Nikiforov, "Detection of Abrupt Changes: Theory and Application", Prentice Hall 1993, §2.2 and
§2.4: the GLR statistic for a change in the mean of independent Gaussian samples, evaluated over a sliding
window of fixed size).

Under "no step" the difference of the two window means varies by (its variance, `step_variance_rad2`):
- the magnetometer's white noise, over the two windows' lengths: estimated from the before-window by the mean
  square successive difference (J. von Neumann, "Distribution of the ratio of the mean square successive
  difference to the variance", Ann. Math. Statist. 12, 1941), which a slow drift of the innovation does not
  inflate, nor a step in the after-window — the stated noise (the rest figure of a real sensor) is kept for the
  filter's update, the measured one is what this test weighs;
- the filter's tilt error, which turns the magnetometer heading by tan(dip) as much, taken as changing by its
  full σ between the windows (√2 σ);
- the gyro over the span: its vertical bias's uncertainty times the span and its angle random walk;
- the filter's own heading corrections (by the GNSS) between the windows: up to its yaw σ at each (2 P_ψψ);
- the magnetometer's slowly varying (calibration, learned-iron) error, which is a function of heading: over a
  heading change Δψ a first harmonic of RMS σ_b changes by at most √2 σ_b·Δψ (Δψ ≤ 2 rad, beyond which the
  harmonic's full swing 2√2 σ_b bounds it). A turn therefore widens the test, a straight leg leaves it at the
  noise; an uncalibrated magnetometer (σ_b tens of degrees) is not tested by it in turns at all.
A step is declared when the difference is beyond `gate_sigma` of that; the caller rejects the magnetometer.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

from ahrsd.core.angles import wrap_pi_float


@dataclass
class MagStepDetector:
    """The two-window test on the magnetometer heading's innovation (see the module docstring). `add` at every
    heading check while the magnetometer is used; `restart` whenever the innovation's reference moves by itself
    (a yaw reset, a learned iron update, a rejection or re-entry)."""

    before_s: float = 5.0          # the reference window
    after_s: float = 2.0           # the window tested against it: the detection delay after a step
    gate_sigma: float = 5.0
    min_before: int = 10           # checks in the reference window before anything is tested (2 s at 5 Hz)
    min_after: int = 5
    max_heading_span_rad: float = 2.0
    detections: int = 0
    last_step_rad: float = math.nan   # the step (after − before, rad) at the latest detection
    statistic: float = math.nan       # the latest |after − before| / its σ (NaN: not tested)
    _checks: deque = field(default_factory=deque, repr=False)   # (t_s, innovation_rad, yaw_rad)

    def restart(self) -> None:
        self._checks.clear()
        self.statistic = math.nan

    def add(self, t_s: float, innovation_rad: float, yaw_rad: float, yaw_var_rad2: float, bias_var_rad2: float,
            tilt_heading_var_rad2: float, gyro_bias_var_rad2_s2: float, gyro_arw_rad_s_sqrt_hz: float) -> float | None:
        """One check's innovation (magnetometer heading − filter heading) and the filter's yaw; returns the step
        (rad, after − before) when one is detected (the windows then start again), else None.
        yaw_var: the filter's yaw variance, rad²; bias_var: the magnetometer heading's slowly varying error
        variance (calibration or learned iron, rad²); tilt_heading_var: the filter's tilt variance times
        tan²(dip), rad²; gyro_bias_var: the vertical gyro bias's variance, rad²/s²; gyro_arw: its angle random
        walk, rad/s/√Hz."""
        checks = self._checks
        checks.append((t_s, innovation_rad, yaw_rad))
        start = t_s - self.after_s - self.before_s
        while checks and checks[0][0] <= start:
            checks.popleft()
        split = t_s - self.after_s
        before = [c for c in checks if c[0] <= split]
        after = [c for c in checks if c[0] > split]
        self.statistic = math.nan
        if len(before) < self.min_before or len(after) < self.min_after:
            return None
        mean_before = sum(c[1] for c in before) / len(before)
        mean_after = sum(c[1] for c in after) / len(after)
        step = mean_after - mean_before
        var = self.step_variance_rad2(before, len(after), yaw_var_rad2, bias_var_rad2, tilt_heading_var_rad2,
                                      gyro_bias_var_rad2_s2, gyro_arw_rad_s_sqrt_hz)
        self.statistic = abs(step) / math.sqrt(var) if var > 0.0 else math.inf
        if step * step <= self.gate_sigma ** 2 * var:
            return None
        self.detections += 1
        self.last_step_rad = step
        self.restart()
        return step

    def step_variance_rad2(self, before: list, n_after: int, yaw_var_rad2: float, bias_var_rad2: float,
                           tilt_heading_var_rad2: float, gyro_bias_var_rad2_s2: float,
                           gyro_arw_rad_s_sqrt_hz: float) -> float:
        """The variance of (mean after − mean before) without a step (module docstring), rad²."""
        inn = [c[1] for c in before]
        white = sum((b - a) ** 2 for a, b in zip(inn, inn[1:])) / (2.0 * (len(inn) - 1))
        span_s = self._checks[-1][0] - self._checks[0][0]
        yaws = [c[2] for c in self._checks]
        turned = min(sum(abs(wrap_pi_float(b - a)) for a, b in zip(yaws, yaws[1:])), self.max_heading_span_rad)
        return (white * (1.0 / len(inn) + 1.0 / n_after)
                + 2.0 * tilt_heading_var_rad2 + 2.0 * yaw_var_rad2
                + gyro_bias_var_rad2_s2 * span_s ** 2 + gyro_arw_rad_s_sqrt_hz ** 2 * span_s
                + 2.0 * bias_var_rad2 * turned ** 2)
