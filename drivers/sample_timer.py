"""Sample timing for a chip without a sample counter or data-ready line: time stamps on the chip's sample grid
in CLOCK_MONOTONIC seconds, sample indices, and the samples lost between reads, from the host clock alone.
The one timing path of every chip reader (`ahrsd run`, `record`, `calibrate --live`: drivers.chip_source)."""

from __future__ import annotations

import math


class SampleTimer:
    """Time stamps and sample indices for a chip that keeps only its latest sample (the ADIS16405).

    The chip produces sample k at ready_k = φ + k·P on its own clock and has no sample counter, so gaps can
    only be seen from the host clock. A read is a transfer that starts after t_start (`read_time`) and ends
    before t_end (`read_end`); the chip latches its newest sample somewhere in between. The phase φ is
    bracketed by the reads themselves: a fresh sample k proves ready_k ≤ t_end, i.e. φ ≤ t_end − k·P (upper
    bound `hi`); a stale read proves the next sample was not ready at t_start, φ > t_start − (k_last+1)·P
    (lower bound `lo`). Reading at the middle of the bracket bisects it, so within a few samples the reader
    wakes just after each sample is ready. Both bounds leak outwards so the lock follows clock drift and
    recovers from a wrong start.

    The index of a fresh read is the LARGEST one the bracket allows, k = ⌈(t_end − lo)/P⌉ − 1 (never less
    than k_last + 1): as long as `lo` is a true lower bound, the index is never below the chip's, so a lost
    sample is never hidden. The index is only an upper bound when the read (or the bracket) straddles a
    ready time — the smallest index allowed, ⌊(t_start − hi)/P⌋, is lower; then up to the difference of the
    lost samples counted may be phantoms. Those reads and samples are counted (`ambiguous_reads`,
    `ambiguous_samples`) so the loss count is conservative and its uncertainty reported. (Earlier versions
    took the index from the wake time, before the transfer: a transfer delayed past the next ready time got
    an index one too low, the following stale read then pushed `lo` past the true phase, and the lock slid
    by a whole period — a real lost sample never counted.)
    Time stamps t_s = φ_hi + k·P lie on the exact sample grid, in CLOCK_MONOTONIC seconds.
    """

    HI_LEAK_S_PER_S = 100e-6   # upper bound relaxes: oscillator drift between chip and host
    # The lower bound only rises on stale (too early) reads; if the reads all land late (wakes delayed,
    # or a wrong first guess) nothing would ever pull the estimate earlier, so it relaxes faster: the
    # reader then probes a little earlier until it meets a stale read (an occasional extra read).
    LO_LEAK_S_PER_S = 1e-3
    GUARD_S = 50e-6         # read this much after the predicted ready time

    def __init__(self, period_s: float):
        self.period_s = period_s
        self.lo: float | None = None   # φ > lo
        self.hi: float | None = None   # φ ≤ hi
        self.k = -1                    # index of the last fresh sample
        self._t_lo = 0.0
        self._t_hi = 0.0

    def _bracket(self, read_time: float, end: float) -> tuple[float, float, int, int]:
        """The bounds (lo, hi) leaked up to `read_time`, and the largest and the smallest index a fresh read between
        `read_time` and `end` allows with the phase in (lo, hi]: the latest k with ready_k ≤ end for some φ in the
        bracket (the largest k with end − k·P > lo), and the latest with ready_k ≤ read_time even at φ = hi;
        neither below the one after the last. One method for both (the reader's every fresh read asks both: a
        Python frame less after each wake's cold caches, docs/daemon.md "Performance")."""
        P = self.period_s
        hi = self.hi + self.HI_LEAK_S_PER_S * (read_time - self._t_hi)
        lo = max(self.lo - self.LO_LEAK_S_PER_S * (read_time - self._t_lo), hi - P)   # φ mod P
        first = self.k + 1
        return lo, hi, max(first, math.ceil((end - lo) / P) - 1), max(first, math.floor((read_time - hi) / P))

    def _leak(self, now: float) -> None:
        self.lo, self.hi, _k, _k_min = self._bracket(now, now)
        self._t_hi = self._t_lo = now

    ambiguous_reads = 0     # fresh reads whose index was not unique (the largest allowed was taken)
    ambiguous_samples = 0   # lost samples counted at those reads that may be phantoms (upper bound)
    waits_for_edges = False  # a reader sleeps until next_read_time (drivers.data_ready's timer can wait instead)

    def fresh(self, read_time: float, read_end: float | None = None,
              newer_ready: bool = False) -> tuple[float, int, int]:
        """A new sample was read by a transfer between `read_time` and `read_end` (default: the same):
        its (t_s, index, samples lost before it). newer_ready: the read saw that a newer sample was ready by
        `read_end` (register reads after the burst), so the one read became ready at least a period earlier."""
        P = self.period_s
        end = read_time if read_end is None else read_end
        if newer_ready:
            end -= P
        if self.hi is None:
            # Sample 0 is the newest at the latch, so φ lies in (read_time − P, end]. A bracket wider than one
            # period would be cut at hi − P by the next leak, i.e. at the later phase, which indexes every
            # later read one low if the sample became ready during the transfer. Cut it at the earlier phase
            # instead (φ ≤ read_time): at worst one phantom loss, counted as ambiguous.
            self.hi, self.lo, self.k = read_time, read_time - P, 0
            self._hi_fresh, self._lo_fresh = self.hi, self.lo
            self._t_hi = self._t_lo = read_time
            if end > read_time:
                self.ambiguous_reads += 1
                self.ambiguous_samples += 1
            return read_time, 0, 0
        return self.fresh_after_first(read_time, end, certain_only=False)

    def fresh_if_certain(self, read_time: float, read_end: float) -> tuple[float, int, int] | None:
        """`fresh(read_time, read_end)` when `index_uncertain(read_time, read_end)` is False; else None, and nothing
        changed (the caller asks the chip: drivers.chip_source). The bracket is leaked and the index range worked
        out once: the reader's every fresh read asks both, one after the other."""
        if self.hi is None:
            return self.fresh(read_time, read_end)
        return self.fresh_after_first(read_time, read_end, certain_only=True)

    _hi_fresh: float | None = None      # the bracket after the last fresh read (StallAware's stale reads go back to it)
    _lo_fresh: float | None = None

    def fresh_after_first(self, read_time: float, end: float, certain_only: bool) -> tuple[float, int, int] | None:
        """`fresh` once the first sample was taken (`hi` set), for a transfer between `read_time` and `end`:
        the bracket leaked to `read_time`, the largest index it allows taken as the newest sample (the ambiguity
        counted), the bracket narrowed by its ready time. certain_only: None instead, and nothing changed, when
        the index is not unique. One method for both (the reader's common read calls it directly:
        drivers.chip_source), the bracket kept in locals until it is stored once."""
        lo, hi, k, k_min = self._bracket(read_time, end)
        if k > k_min:
            if certain_only:
                return None
            self.ambiguous_reads += 1
            self.ambiguous_samples += k - k_min
        self._t_hi = self._t_lo = read_time
        P = self.period_s
        lost = k - self.k - 1
        self.k = k
        self._consumed_upto = -1
        hi = min(hi, end - k * P)
        if lo >= hi:                                 # only after k was forced up: trust the newest read
            lo = hi - 0.25 * P
        self.lo = self._lo_fresh = lo
        self.hi = self._hi_fresh = hi
        return hi + k * P, k, lost

    def index_uncertain(self, read_time: float, read_end: float) -> bool:
        """Would a fresh read between `read_time` and `read_end` get an index that is only the largest allowed (a
        sample may have become ready during the transfer, or the phase bracket straddles a ready time)? Then a
        register read after the burst tells which sample it was (drivers.chip_source: its ND says whether a
        newer sample is ready)."""
        if self.hi is None:
            return False
        _lo, _hi, k, k_min = self._bracket(read_time, read_end)
        return k > k_min

    def stale(self, read_time: float) -> None:
        """The chip had no new sample at `read_time`."""
        if self.hi is None:
            return
        self._leak(read_time)
        self.lo = max(self.lo, read_time - (max(self.k, self._consumed_upto) + 1) * self.period_s)
        if self.lo >= self.hi:
            self.hi = self.lo + self.GUARD_S

    _consumed_upto = -1     # the newest index a read since the last fresh sample may have consumed unseen

    def may_have_consumed(self, read_end: float) -> None:
        """A read that ended at `read_end` may have taken a new sample without it reaching us: a rejected
        frame, or more register reads after the burst (they clear ND). Any sample ready by then may be gone,
        so until the next fresh sample a stale read only proves that the one after the newest such sample
        was not ready (taken as k+1, the lock would slide a period late and a lost sample would never be
        counted)."""
        if self.hi is None:
            return
        self._leak(read_end)
        newest = math.ceil((read_end - self.lo) / self.period_s) - 1
        self._consumed_upto = max(self._consumed_upto, self.k, newest)

    def next_read_time(self) -> float:
        """When to read for the next sample (0 before the first one: now)."""
        if self.hi is None:
            return 0.0
        return 0.5 * (self.lo + self.hi) + (self.k + 1) * self.period_s + self.GUARD_S


class StallAwareSampleTimer(SampleTimer):
    """A SampleTimer that tells a data-ready stall from a phase error.

    The base class learns the chip's sample phase from stale reads; when a stale read comes more than
    STALL_PERIODS after the sample was due, it drags its phase estimate forward, so after a stall of S
    samples the sample index does not advance: the S samples the chip never produced are not counted as lost.
    Here, a read that late is a stall: the phase is kept, and the first sample after the stall gets the
    index its time says (the gap is counted, the estimator sees the real Δt).
    """

    STALL_PERIODS = 2.0

    stalled_reads = 0

    def stale(self, read_time: float) -> None:
        if (self._hi_fresh is not None
                and read_time - (self.k + 1) * self.period_s >= self._hi_fresh + self.STALL_PERIODS * self.period_s):
            # undo what the first stale reads of the stall did: they were taken as "sample k+1 not ready",
            # but the stalled chip had produced it (ND held clear); that raised lo past the true phase (so the
            # sample after the stall came out one index low) even when it did not drag hi
            self.hi, self.lo = self._hi_fresh, self._lo_fresh
            self.stalled_reads += 1
            return
        super().stale(read_time)
