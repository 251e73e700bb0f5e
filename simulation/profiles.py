"""Smooth one-dimensional motion profiles with exact integrals, for building trajectories.

A `RateProfile` is a piecewise rate r(t): each segment blends from `rate_start` to `rate_end` with a raised
cosine, so the rate is continuous (a real table or vehicle cannot jump in rate) and its integral, the angle, is
exact in closed form: no numerical integration, so truth attitude and truth rate never disagree.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, slots=True)
class Segment:
    """`duration_s` seconds during which the rate goes from `rate_start` to `rate_end` (raised-cosine blend)."""

    duration_s: float
    rate_start: float
    rate_end: float

    def integral(self) -> float:
        return 0.5 * (self.rate_start + self.rate_end) * self.duration_s


def hold(duration_s: float, rate: float = 0.0) -> Segment:
    return Segment(duration_s, rate, rate)


def ramp(duration_s: float, rate_start: float, rate_end: float) -> Segment:
    return Segment(duration_s, rate_start, rate_end)


class RateProfile:
    """r(t) and its integral θ(t) = θ0 + ∫₀ᵗ r, built from segments; repeats with its total duration.

    When the profile repeats, θ keeps accumulating (each period adds the same angle), so a heading that turns
    360° per period keeps turning.

    blend "cosine": raised cosine, r is C¹ (its derivative is zero at both ends of a segment, the second
    derivative jumps there). blend "quintic": the smootherstep 10u³ − 15u⁴ + 6u⁵, r is C² (first and second
    derivatives zero at both ends), for quantities whose derivative drives something else (a car's suspension
    pitch follows its acceleration, so the pitch rate follows the jerk and must not jump).
    """

    def __init__(self, segments, angle0: float = 0.0, blend: str = "cosine"):
        if blend not in ("cosine", "quintic"):
            raise ValueError(f"blend must be 'cosine' or 'quintic', got {blend!r}")
        self.blend = blend
        segs = list(segments)
        if not segs or any(s.duration_s <= 0 for s in segs):
            raise ValueError("a RateProfile needs segments of positive duration")
        self.segments = tuple(segs)
        self.angle0 = float(angle0)
        durations = np.array([s.duration_s for s in segs])
        self._t0 = np.concatenate(([0.0], np.cumsum(durations)[:-1]))
        self._dur = durations
        self._r0 = np.array([s.rate_start for s in segs])
        self._r1 = np.array([s.rate_end for s in segs])
        self._a0 = np.concatenate(([0.0], np.cumsum([s.integral() for s in segs])[:-1]))
        self.period_s = float(durations.sum())
        self.angle_per_period = float(sum(s.integral() for s in segs))

    def _locate(self, t):
        t = np.asarray(t, dtype=float)
        n_period = np.floor(t / self.period_s)
        tp = t - n_period * self.period_s
        # np.clip's Python wrapper costs more than the search: the same bounds with the two ufuncs
        k = np.minimum(np.maximum(np.searchsorted(self._t0, tp, side="right") - 1, 0), len(self._dur) - 1)
        tau = tp - self._t0[k]
        return n_period, k, tau

    def rate(self, t) -> np.ndarray:
        _, k, tau = self._locate(t)
        u = tau / self._dur[k]
        if self.blend == "quintic":
            blend = u**3 * (10.0 - 15.0 * u + 6.0 * u * u)
        else:
            blend = 0.5 * (1.0 - np.cos(np.pi * u))
        return self._r0[k] + (self._r1[k] - self._r0[k]) * blend

    def angle(self, t) -> np.ndarray:
        n_period, k, tau = self._locate(t)
        T = self._dur[k]
        d = self._r1[k] - self._r0[k]
        if self.blend == "quintic":
            u = tau / T
            within = self._r0[k] * tau + d * T * u**4 * (2.5 - 3.0 * u + u * u)   # ∫ smootherstep (half at u=1)
        else:
            within = self._r0[k] * tau + 0.5 * d * (tau - T / np.pi * np.sin(np.pi * tau / T))
        return self.angle0 + n_period * self.angle_per_period + self._a0[k] + within

    def accel(self, t) -> np.ndarray:
        """dr/dt (rate of change of the rate)."""
        _, k, tau = self._locate(t)
        T = self._dur[k]
        if self.blend == "quintic":
            u = tau / T
            return (self._r1[k] - self._r0[k]) * 30.0 * u * u * (1.0 - u) ** 2 / T
        return (self._r1[k] - self._r0[k]) * 0.5 * np.pi / T * np.sin(np.pi * tau / T)


def smoothstep(x):
    """3x² − 2x³ on [0, 1], clamped: a C¹ blend with zero slope at both ends."""
    x = np.clip(np.asarray(x, dtype=float), 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)
