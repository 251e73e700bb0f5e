"""The ADIS16405 as a sensor source: one burst read per chip sample, timed by the SampleTimer.

Works on any SpiBus: the real chip (`SpidevBus`) or the byte-level simulated chip (`SimulatedAdis16405`).
The chip has no sample counter, so the time stamp, the sample index and the samples lost before a read come
from the host clock (drivers.sample_timer); the driver builds the sample with them (one ImuSample per read).
"""

from __future__ import annotations

import logging
import math
import time

from operator import ge as _ge

from ahrsd.core.sample import ImuSample, SampleFlags
from ahrsd.drivers import registers as R
from ahrsd.drivers.adis16405 import _SUPPLY_MAX_LSB, _SUPPLY_MIN_LSB, _UNPACK_BURST, Adis16405
from ahrsd.drivers.errors import FrameError
from ahrsd.drivers.sample_timer import SampleTimer
from ahrsd.drivers.source_interface import LiveSource

log = logging.getLogger(__name__)

ADIS16405_RATE_HZ = 819.2          # ADIS16405 datasheet: default SMPL_PRD = 0x01 → 819.2 SPS
# IntFlag operators are slow (enum machinery); the per-sample path tests bits on plain ints
_int_and = int.__and__
_STALE, _GAP_BEFORE = int(SampleFlags.STALE), int(SampleFlags.GAP_BEFORE)
# flags of a burst after which the driver read more registers (XGYRO_OUT for the burst bug, DIAG_STAT for an
# alarm): reading an output register clears ND, so a sample that became ready meanwhile was consumed unseen
_MORE_READS = int(SampleFlags.BURST_BUG_RECOVERED | SampleFlags.GYRO_INVALID | SampleFlags.ALARM)
# register reads after a burst whose index the host clock leaves open (`_checked_index`): each ends the doubt or
# moves the instant at which the burst's sample is known to be the newest later, until it is past the phase
# bracket's width; at most this many reads and this share of a period after the burst (a stepped clock that
# register reads do not move must not loop, nor a bracket as wide as a period keep the reader busy)
INDEX_PROBES = 64
INDEX_PROBE_PERIODS = 0.5
# a burst that took a period or longer (preempted inside the transfer) is not checked: a register read after it
# settles its index only if burst and register read together end within a period
CHECKABLE_READ_PERIODS = 1.0
_NEW_DATA = int(SampleFlags.NEW_DATA)
_ND, _EA, _FLAG_BITS = R.ND, R.EA, R.ND | R.EA


class ChipSource(LiveSource):
    """The ADIS16405 driver read once per sample (`read_one`) at the time the timer asks for (`next_read_time`).

    clock: the host clock of the reads (CLOCK_MONOTONIC, the same clock as the reader's `now`). The read is
        bracketed by the time just before and just after the transfer: the chip latched the sample somewhere in
        between, and a late transfer (preempted after the wake) must not be indexed by the wake time. None:
        only the `now` given to `read_one` is used.
    """

    description: str
    sample_rate_hz: float
    per_sample = True          # read once per chip sample on the phase lock (see SampleTimer)
    monotonic_offset_s = 0.0   # the SampleTimer stamps samples in CLOCK_MONOTONIC already

    def __init__(self, driver: Adis16405, bus, description: str, clock=None, timer: SampleTimer | None = None):
        self.driver = driver
        self.bus = bus
        self.description = description
        self.clock = clock
        self.sample_rate_hz = float(driver.sample_rate_hz)     # the chip's, as read back (its default until start)
        self.timer = timer if timer is not None else SampleTimer(1.0 / self.sample_rate_hz)
        # the common read steps the timer itself (drivers.data_ready's timer counts edges instead)
        self._common_timer = isinstance(self.timer, SampleTimer)
        self.stale_reads = 0
        self.lost_samples = 0
        self._read_start = 0.0

    def read_one(self, now: float) -> ImuSample | None:
        """One burst read at host time `now`: the new sample (t_s on the sample grid in CLOCK_MONOTONIC
        seconds, counter = sample index, GAP_BEFORE after lost samples), or None when the chip has no new
        sample yet (ND clear). Raises FrameError (one corrupt frame) or BusError.

        The common read of the reader process (records, a SampleTimer with its first sample taken: a clean fresh
        frame whose index the host clock settles) is decoded here, in this function: a Python frame less is CPU
        less after every wake's cold caches (docs/daemon.md "Performance"). Any other read is the driver's and
        the timer's general path.

        The common read: ND in every word, no EA, supply and every axis within bounds, no burst-bug suspicion,
        the driver not holding a newer sample's ND, a transfer shorter than CHECKABLE_READ_PERIODS and a unique
        index. The checks, the timer's step and the record, with the driver's bounds and the timer's arithmetic
        (fresh_after_first), the stuck-axis check and the record (Adis16405._check_stuck, _sample) shared.
        Decides before it changes anything; any other frame goes, as read, to the driver's general path
        (Adis16405.decode_burst with `_stamp`), which gives the same sample, counters and timer state
        (tests/test_common_read.py, tools/reader_digest.py)."""
        clock = self.clock
        if clock is not None:
            now = max(now, clock())
        self._read_start = now
        driver, timer = self.driver, self.timer
        out = None                    # the common read's (t_s, index, lost): None, the general path's read
        try:
            if driver.samples_as_records and self._common_timer and timer.hi is not None:
                rx = driver.read_burst()
                w0, w1, w2, w3, w4, w5, w6, w7, w8, w9, w10, _ = _UNPACK_BURST(rx, 2)
                supply = w0 & 0x3FFF
                # ND in every checked word and EA in none (Adis16405.decode_burst's agreement check, its common
                # answer), the driver not holding a newer sample's ND
                if not ((w0 & w1 & w2 & w3 & w4 & w5 & w6 & w7 & w8 & w9 & _FLAG_BITS) != _ND
                        or (w0 | w1 | w2 | w3 | w4 | w5 | w6 | w7 | w8 | w9) & _EA
                        or not _SUPPLY_MIN_LSB <= supply <= _SUPPLY_MAX_LSB or driver.newer_sample_taken):
                    gx = ((w1 & 0x3FFF) ^ 0x2000) - 0x2000
                    raw9 = [gx, ((w2 & 0x3FFF) ^ 0x2000) - 0x2000, ((w3 & 0x3FFF) ^ 0x2000) - 0x2000,
                            ((w4 & 0x3FFF) ^ 0x2000) - 0x2000, ((w5 & 0x3FFF) ^ 0x2000) - 0x2000,
                            ((w6 & 0x3FFF) ^ 0x2000) - 0x2000, ((w7 & 0x3FFF) ^ 0x2000) - 0x2000,
                            ((w8 & 0x3FFF) ^ 0x2000) - 0x2000, ((w9 & 0x3FFF) ^ 0x2000) - 0x2000]
                    prev_gx = driver._prev_gx
                    # the driver's burst-bug suspicion (decode_burst) and full scale (beyond which lies the
                    # plausibility bound)
                    if not ((not (w1 & 0x2000) and (gx > driver._gyro_range_lsb or (
                            gx - prev_gx > driver._jump_lsb if prev_gx is not None else gx > driver._jump_lsb)))
                            or any(map(_ge, map(abs, raw9), driver._full_scale9))):
                        end = now if clock is None else clock()
                        if end - now < CHECKABLE_READ_PERIODS * timer.period_s:
                            out = timer.fresh_after_first(now, end, True)     # None: the index is uncertain
                if out is None:
                    s = driver.decode_burst(rx, self._stamp)
            else:
                s = driver.read_sample(self._stamp)
        except FrameError:
            # the rejected frame may have carried (and cleared) a new sample
            timer.may_have_consumed(now if clock is None else clock())
            raise
        if out is None:
            return None if _int_and(s.flags, _STALE) else s
        # from here on the read is taken: the driver's state as decode_burst leaves it after a clean fresh frame
        driver.counters["new_samples"] += 1
        driver._burst_supply_lsb = supply
        driver._prev_gx = gx
        flags = _NEW_DATA | driver._check_stuck(raw9)
        if _int_and(flags, _MORE_READS):
            timer.may_have_consumed(end)
        t_s, k, lost = out
        if lost:
            self.lost_samples += lost
            flags |= _GAP_BEFORE
        return driver._sample(t_s, k, raw9, w10, supply, flags, 0)

    def _stamp(self, flags: int) -> tuple[float, int, int]:
        """Called by the driver once the frame's flags are known: (t_s, index, extra flags) of the sample."""
        timer, clock, now = self.timer, self.clock, self._read_start
        end = now if clock is None else clock()
        if _int_and(flags, _STALE):
            self.stale_reads += 1
            if _int_and(flags, _MORE_READS):
                timer.may_have_consumed(end)
            timer.stale(now)          # not ready at `now` or later: `now` is the safe bound
            return math.nan, timer.k, 0
        newer = self.driver.newer_sample_taken
        if newer or end - now >= CHECKABLE_READ_PERIODS * timer.period_s:
            t_s, k, lost = timer.fresh(now, end, newer)
        else:
            # fresh unless the index is uncertain (the timer works the bracket out once for both)
            out = timer.fresh_if_certain(now, end)
            t_s, k, lost = self._checked_index(now, end) if out is None else out
        if _int_and(flags, _MORE_READS):
            timer.may_have_consumed(end)
        if lost:
            self.lost_samples += lost
            return t_s, k, _GAP_BEFORE
        return t_s, k, 0

    def _checked_index(self, now: float, end: float) -> tuple[float, int, int]:
        """(t_s, index, lost) of a fresh burst read between `now` and `end` whose index the host clock leaves
        open (a sample may have become ready during the transfer, or the phase bracket straddles a ready time):
        the chip says which sample it was. An output register read after the burst (`take_newer_sample`): ND
        set, a sample newer than the burst's is ready, so the burst's was the one before (and the next burst
        returns the newer one as new); ND clear, the burst's sample was still the newest when the register read
        began, as if the burst had been read at that instant — read again until that instant is past the
        bracket's doubt (at most INDEX_PROBES reads within INDEX_PROBE_PERIODS of a period). Taking the largest index the host
        clock allows instead (so that a lost sample is never hidden) was one too high whenever the burst had
        latched the sample before (a real-time `record --sim` on a loaded machine: rows one sample off)."""
        timer, clock, driver = self.timer, self.clock, self.driver
        newest_at = now               # the burst's sample was the newest at its latch, at or after `now`
        for probe in range(INDEX_PROBES):
            start = end if clock is None else clock()
            if driver.take_newer_sample():    # a corrupt answer raises FrameError: read_one's, the sample lost
                return timer.fresh(newest_at, end if clock is None else clock(), newer_ready=True)
            newest_at = start
            if (probe == INDEX_PROBES - 1 or start - end > INDEX_PROBE_PERIODS * timer.period_s
                    or not timer.index_uncertain(start, start)):
                break
        out = timer.fresh(newest_at, newest_at)
        timer.stale(newest_at)
        return out

    def next_read_time(self) -> float:
        return self.timer.next_read_time()

    def poll(self, now: float | None = None) -> list[ImuSample]:
        s = self.read_one(time.monotonic() if now is None else now)
        return [] if s is None else [s]

    def counters(self) -> dict:
        c = dict(self.driver.counters)
        c["stale_reads"] = self.stale_reads
        c["lost_samples_host"] = self.lost_samples
        c["index_ambiguous_reads"] = self.timer.ambiguous_reads
        c["index_ambiguous_samples"] = self.timer.ambiguous_samples
        return c

    def close(self) -> None:
        try:
            self.bus.close()
        except Exception:  # noqa: BLE001 - closing must not mask the shutdown reason
            log.debug("closing the SPI bus failed", exc_info=True)
