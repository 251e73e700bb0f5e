"""Gaps in a recording: the samples missing between those recorded, and whether a fit can use it.

A recording lists the chip's samples in order; one the host missed leaves a gap (drivers/recording.py: the
`counter` column is the sample index since the driver started, and a gap increments it; t_s is that index
times the sample period). `ahrsd record` counts what it lost, but the file is what a fit reads, so the gaps are
counted here from the file itself: from the counter when the recording has one, else from t_s against its
median step (a gap of n samples is a step of n + 1 periods).

Whether a gap matters depends on the fit (docs/calibration.md, "Gaps in a recording"):
- a fit that averages (still periods, Allan, an ellipsoid through the samples) takes fewer samples: its result is
  as good as one from a shorter recording, so the gaps are only reported;
- a fit that relates samples across time (the rate-table reference rate differentiated from the truth attitude,
  an estimator run over the recording) spans each gap with one step: a rotation of π or more during the gap
  aliases, and an estimator's step across it holds one gyro sample for the whole gap. Those fits refuse a
  recording whose longest gap is above `MAX_GAP_INTEGRATING_S` (why that number: the constant's comment).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# The longest gap a fit that relates samples across time accepts. Across a gap of T s the rate-table reference is
# the rotation vector of the truth attitude's change divided by T: exact for a constant rate while the rotation
# stays below π (2 s at the thesis's 90 °/s table), aliased above it. An estimator run over the recording steps
# across the gap with one gyro sample: during a table's raised-cosine ramp (90 °/s in 2 s, peak acceleration
# α = π/2 · 90/2 ≈ 71 °/s²) that misses ½·α·T² of rotation. At T = 0.05 s that is 0.09° per gap, 1.2e-4 of a
# two-turn (720°) rotation: the size of the rate-table fit's own 1σ on a matrix entry (~1e-4,
# tests/test_cal_gyro.py), so a longer gap is refused rather than let its bias reach the fit. 0.05 s is 41
# samples at 819.2 SPS and one sample at 20 Hz.
MAX_GAP_INTEGRATING_S = 0.05


@dataclass(frozen=True)
class RecordingGaps:
    """The gaps of one recording, counted in samples of its own rate."""

    samples: int                # samples in the recording
    missing_samples: int        # samples the gaps leave out
    gaps: int                   # how many places samples are missing
    longest_gap_samples: int
    sample_period_s: float
    counted_from: str           # "counter" or "t_s"

    @property
    def longest_gap_s(self) -> float:
        return self.longest_gap_samples * self.sample_period_s

    @property
    def missing_share(self) -> float:
        """Missing samples as a share of those the recording's span should hold."""
        total = self.samples + self.missing_samples
        return self.missing_samples / total if total else 0.0

    def to_json_dict(self) -> dict:
        return {"samples": self.samples, "missing_samples": self.missing_samples, "gaps": self.gaps,
                "longest_gap_samples": self.longest_gap_samples, "longest_gap_s": self.longest_gap_s,
                "missing_share": self.missing_share, "counted_from": self.counted_from}

    def describe(self) -> str:
        """One line for a person ("no gaps", or what is missing and the longest gap)."""
        if not self.gaps:
            return f"gaps: none ({self.samples} samples, counted from {self.counted_from})"
        return (f"gaps: {self.missing_samples} samples missing ({self.missing_share:.1%}) in {self.gaps} gaps, the "
                f"longest {self.longest_gap_samples} samples ({self.longest_gap_s:.3g} s; counted from "
                f"{self.counted_from})")


class GapCounter:
    """Counts the gaps of a recording read a chunk at a time (`calibrate allan` streams a long file): the step
    from one chunk's last sample to the next chunk's first is counted too. The sample period is the first
    chunk's median step."""

    def __init__(self) -> None:
        self._samples = 0
        self._missing = 0
        self._gaps = 0
        self._longest = 0
        self._period_s = math.nan
        self._by_counter: bool | None = None     # fixed by the first chunk
        self._last_t_s: float | None = None
        self._last_counter: float | None = None

    def add(self, t_s, counter=None) -> None:
        """The next chunk's time stamps and, when the recording has one, its sample counter."""
        t = np.asarray(t_s, dtype=np.float64)
        if not len(t):
            return
        if self._by_counter is None:
            # A counter that never advances (a tool that wrote 0 throughout) says nothing: the time stamps do.
            self._by_counter = (counter is not None and bool(np.all(np.isfinite(counter)))
                                and (len(t) < 2 or bool(np.any(np.diff(counter) > 0))))
            if len(t) >= 2:
                self._period_s = float(np.median(np.diff(t)))
        if self._by_counter:
            c = np.asarray(counter, dtype=np.float64)
            steps = np.diff(c if self._last_counter is None else np.r_[self._last_counter, c])
            self._last_counter = float(c[-1])
        elif math.isfinite(self._period_s) and self._period_s > 0:
            steps = np.rint(np.diff(t if self._last_t_s is None else np.r_[self._last_t_s, t]) / self._period_s)
        else:
            steps = np.zeros(0)
        self._last_t_s = float(t[-1])
        missing = np.where(steps > 1, steps - 1, 0).astype(np.int64)
        self._samples += len(t)
        self._missing += int(missing.sum())
        self._gaps += int(np.count_nonzero(missing))
        self._longest = max(self._longest, int(missing.max(initial=0)))

    def result(self) -> RecordingGaps:
        return RecordingGaps(self._samples, self._missing, self._gaps, self._longest, self._period_s,
                             "counter" if self._by_counter else "t_s")


def find_gaps(t_s, counter=None) -> RecordingGaps:
    """The gaps of a recording from its sample counter (when given and finite throughout) or its time stamps
    against their median step. A step of k > 1 counts or periods is a gap of k − 1 samples; a step back (a
    restarted driver) is no gap."""
    counted = GapCounter()
    counted.add(t_s, counter)
    return counted.result()


def integrating_refusal(gaps: RecordingGaps, what: str) -> str | None:
    """Why a fit that relates samples across time (`what`: the fit, for the message) cannot use the recording,
    or None when its longest gap is short enough (MAX_GAP_INTEGRATING_S)."""
    if gaps.longest_gap_s <= MAX_GAP_INTEGRATING_S * (1.0 + 1e-9):    # one 20 Hz sample is exactly the limit
        return None
    return (f"the recording has gaps ({gaps.missing_samples} samples missing, {gaps.missing_share:.1%}, in "
            f"{gaps.gaps} gaps; the longest {gaps.longest_gap_samples} samples, {gaps.longest_gap_s:.3g} s): "
            f"{what} relates samples across time and a gap longer than {MAX_GAP_INTEGRATING_S:g} s biases it; "
            "record again on a less loaded machine (ahrsd record reports the samples it lost), or record with "
            "--seconds, which for --sim runs as fast as the machine allows and loses none")
