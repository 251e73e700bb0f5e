"""The learned magnetometer's floor as the trust tests see it: the part of what no learned iron explains that is
still there over the window the heading monitor judges the magnetometer on.

The floor (mag_error_states.learned_floor_var_rad2: `iron_unmodelled_ut` over the horizontal field, at most the
calibration's figure) is, in the rest of the filter, an error correlated over `iron_tau_s` while the vehicle moves:
the iron learner renews it as measurement noise every `iron_tau_s` (IronLearner.update's inflation) and the kernel
fuses it as noise lasting `iron_learned_tau_s`. The trust tests (re-entry, the end of the iron learning, the
heading state) compare a *slowly varying* variance with the monitor's trust limit over `reentry_s` of agreement.
Counted there at its full variance, such an error reads as a permanent heading offset, which the rest of the filter
never takes it for; at a weak horizontal field (Punta Arenas, H 19.6 µT: 1 µT / H = 2.92°) it leaves the learned
iron 0.69° under a 3° limit, which the iron learned against a GNSS yaw of σ ~1° never reaches: the learning never
ends (docs/gnss.md "(pa96)").

What a first-order Gauss–Markov error of variance σ² and correlation time τ leaves in its mean over a window T
(Papoulis, Probability, Random Variables and Stochastic Processes, the variance of a time average,
(1/T²)∫∫ σ² e^(−|t−s|/τ) ds dt):

    σ² · 2 (τ/T)² (T/τ − 1 + e^(−T/τ))

1 for T ≪ τ (the error stays), 2τ/T for T ≫ τ. A calibration's own figure (the floor where it is the smaller) is
not averaged: nothing says it changes while the vehicle moves.
"""

from __future__ import annotations

import math

from .mag_error_states import learned_floor_var_rad2


def time_average_share(corr_s: float, window_s: float) -> float:
    """The share of a first-order Gauss–Markov error's variance left in its mean over `window_s` (s), its
    correlation time `corr_s` (s): 1 where either is not positive (nothing averages)."""
    if not (corr_s > 0.0 and window_s > 0.0) or math.isinf(corr_s):
        return 1.0
    r = window_s / corr_s
    return min(1.0, 2.0 * (r - 1.0 + math.exp(-r)) / (r * r))


def slow_floor_var_rad2(p, h2_ut2: float, window_s: float) -> float:
    """The learned magnetometer's floor over the trust window `window_s` (s), rad²: `iron_unmodelled_ut` over the
    horizontal field (h2, µT²) times `time_average_share(iron_tau_s, window_s)`, at most the calibration's own
    figure. `p`: the InsParams in force."""
    return learned_floor_var_rad2(p, h2_ut2, time_average_share(p.iron_tau_s, window_s))
