"""The per-sample path: sample source → calibration → mounting rotation → estimator.

Calibrations are made in the sensor frame (bench calibrations, `ahrsd calibrate`, the field mag-cal session),
so `Calibration.apply` sees the driver's sensor-frame sample; the mounting rotation (sensor → body) comes
after it.

Sources (`SampleSource`) hand over every sample that became available since the previous poll:
* `DriverSource`: the ADIS16405 driver on any SpiBus — the real chip (`SpidevBus`) or the byte-level
  simulated chip (`SimulatedAdis16405` with a real-time clock). Each poll burst-reads until the chip reports
  no new data (ND clear → STALE).
* `ReplaySource`: a recording, paced by its timestamps (or as fast as possible).

`Pipeline.process(raw)` is the hot path (once per sample): it must stay cheap, so the mounting rotation is
skipped when it is the identity and calibration/estimator swaps are single attribute assignments, which the
single-threaded event loop makes atomic between two samples.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Iterator, Protocol

import numpy as np

from ahrsd.drivers.errors import FrameError
from ahrsd.core.sample import ImuSample, SampleFlags

log = logging.getLogger(__name__)

ADIS16405_RATE_HZ = 819.2          # ADIS16405 datasheet: default SMPL_PRD = 0x01 → 819.2 SPS
MAX_SAMPLES_PER_POLL = 64          # bound one poll's work (a stall is reported as a gap, not a burst)
INVALID = SampleFlags.GYRO_INVALID | SampleFlags.ACCEL_INVALID | SampleFlags.MAG_INVALID
# IntFlag operators are slow (enum machinery); the per-sample path tests bits on plain ints
_int_and = int.__and__
_STALE, _INVALID, _GAP_BEFORE = int(SampleFlags.STALE), int(INVALID), int(SampleFlags.GAP_BEFORE)
# flags of a burst after which the driver read more registers (XGYRO_OUT for the burst bug, DIAG_STAT for an
# alarm): reading an output register clears ND, so a sample that became ready meanwhile was consumed unseen
_MORE_READS = int(SampleFlags.BURST_BUG_RECOVERED | SampleFlags.GYRO_INVALID | SampleFlags.ALARM)


class SampleSource(Protocol):
    sample_rate_hz: float
    description: str

    def poll(self) -> list[ImuSample]:
        """Every new sample since the last call (possibly none). Raises DriverError on bus failure."""

    def counters(self) -> dict: ...

    def close(self) -> None: ...


class DriverSource:
    """The ADIS16405 driver: drains the chip on each poll (burst reads until ND is clear)."""

    def __init__(self, driver, bus, description: str, clock=None):
        self.driver = driver
        self.bus = bus
        self.description = description
        # clock: when given (CLOCK_MONOTONIC, the same clock as the reader's `now`), the read is bracketed by
        # the time just before and just after the transfer: the chip latched the sample somewhere in between,
        # and a late transfer (preempted after the wake) must not be indexed by the wake time
        self.clock = clock
        self.sample_rate_hz = float(getattr(driver, "sample_rate_hz", ADIS16405_RATE_HZ) or ADIS16405_RATE_HZ)
        self.timer = SampleTimer(1.0 / self.sample_rate_hz)
        self.stale_reads = 0
        self.lost_samples = 0

    per_sample = True   # read once per chip sample on the phase lock (see SampleTimer)
    monotonic_offset_s = 0.0   # the SampleTimer stamps samples in CLOCK_MONOTONIC already

    def read_one(self, now: float) -> ImuSample | None:
        """One burst read at host time `now`: the new sample (re-timed by the SampleTimer: t_s on the sample
        grid in CLOCK_MONOTONIC seconds, counter = sample index, GAP_BEFORE after lost samples), or None when
        the chip has no new sample yet (ND clear)."""
        clock = self.clock
        if clock is not None:
            now = max(now, clock())
        try:
            s = self.driver.read_sample()
        except FrameError:
            # the rejected frame may have carried (and cleared) a new sample
            self.timer.may_have_consumed(now if clock is None else clock())
            raise
        if _int_and(s.flags, _STALE):
            self.stale_reads += 1
            if _int_and(s.flags, _MORE_READS):
                self.timer.may_have_consumed(now if clock is None else clock())
            self.timer.stale(now)          # not ready at `now` or later: `now` is the safe bound
            return None
        end = now if clock is None else clock()
        t_s, k, lost = self.timer.fresh(now, end)
        if _int_and(s.flags, _MORE_READS):
            self.timer.may_have_consumed(end)
        flags = s.flags
        if lost:
            self.lost_samples += lost
            flags |= SampleFlags.GAP_BEFORE
        return ImuSample(t_s, s.gyro_rad_s, s.accel_m_s2, s.mag_ut, s.temp_c, s.supply_v, flags, s.diag_stat, k)

    def next_read_time(self) -> float:
        return self.timer.next_read_time()

    def poll(self, now: float | None = None) -> list[ImuSample]:
        s = self.read_one(time.monotonic() if now is None else now)
        return [] if s is None else [s]

    def counters(self) -> dict:
        c = dict(getattr(self.driver, "counters", {}) or {})
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


class ReplaySource:
    """Samples from a recording, released when their time comes (realtime) or all at once (fast)."""

    per_sample = False   # polled on a fixed tick; each poll returns every sample that is due
    monotonic_offset_s = 0.0   # CLOCK_MONOTONIC − recording time (set at the first sample)

    def __init__(self, samples: Iterator[ImuSample], description: str, realtime: bool = True,
                 rate_hz: float = ADIS16405_RATE_HZ, clock=time.monotonic):
        self._it = iter(samples)
        self.description = description
        self.realtime = realtime
        self.sample_rate_hz = rate_hz
        self._clock = clock
        self._pending: ImuSample | None = None
        self._t0_clock: float | None = None
        self._t0_sample = 0.0
        self.finished = False

    def poll(self) -> list[ImuSample]:
        out: list[ImuSample] = []
        now = self._clock()
        while len(out) < MAX_SAMPLES_PER_POLL:
            if self._pending is None:
                try:
                    self._pending = next(self._it)
                except StopIteration:
                    self.finished = True
                    break
                if self._t0_clock is None:
                    self._t0_clock, self._t0_sample = now, self._pending.t_s
                    self.monotonic_offset_s = now - self._pending.t_s
            if self.realtime and self._pending.t_s - self._t0_sample > now - self._t0_clock:
                break
            out.append(self._pending)
            self._pending = None
        return out

    def counters(self) -> dict:
        return {}

    def close(self) -> None:
        close = getattr(self._it, "close", None)
        if close:
            close()


def open_source(sensor_cfg, clock=time.monotonic) -> SampleSource:
    """Build the configured source (imports the driver stack lazily)."""
    if sensor_cfg.source == "replay":
        from ahrsd.drivers.recording import iter_samples

        return ReplaySource(iter_samples(sensor_cfg.replay_file), f"replay {sensor_cfg.replay_file}",
                            realtime=sensor_cfg.replay_realtime, clock=clock)
    from ahrsd.drivers.adis16405 import Adis16405

    if sensor_cfg.source == "spi":
        from ahrsd.drivers.spi import SpidevBus

        bus = SpidevBus(sensor_cfg.spi_device)
        description = f"ADIS16405 on {sensor_cfg.spi_device}"
    else:
        from ahrsd.drivers.simulated import SimulatedAdis16405

        bus = SimulatedAdis16405(scenario=sensor_cfg.scenario, seed=sensor_cfg.seed, errors=sensor_cfg.errors,
                                 clock=clock)
        description = f"simulated ADIS16405 ({sensor_cfg.scenario})"
    driver = Adis16405(bus)   # no host clock: the DriverSource's SampleTimer times and counts the samples
    try:
        driver.start()
    except Exception:
        bus.close()
        raise
    return DriverSource(driver, bus, description, clock=clock)


def mounting_matrix(rpy_deg) -> np.ndarray | None:
    """Body←sensor DCM from ZYX Euler angles of the sensor axes in the body frame; None for the identity."""
    r, p, y = (math.radians(float(a)) for a in rpy_deg)
    if r == p == y == 0.0:
        return None
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    # C = Rz(yaw) · Ry(pitch) · Rx(roll), the same convention as C_b^n (design §4)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


@dataclass
class PipelineCounters:
    samples: int = 0
    gaps: int = 0                # discontinuities in the sample counter (one per gap)
    lost_samples: int = 0        # samples missing inside those gaps
    invalid_samples: int = 0     # samples flagged GYRO/ACCEL/MAG_INVALID
    estimator_errors: int = 0


@dataclass
class Pipeline:
    """Driver output in, calibrated sample and attitude estimate out."""

    estimator: object
    calibration: object
    mounting: np.ndarray | None = None
    counters: PipelineCounters = field(default_factory=PipelineCounters)
    last_sample: ImuSample | None = None       # calibrated, body frame
    last_sensor_sample: ImuSample | None = None  # calibrated, sensor frame (before the mounting rotation)
    last_estimate: object | None = None
    _last_counter: int | None = None

    def set_mounting(self, rpy_deg) -> None:
        self.mounting = mounting_matrix(rpy_deg)

    def process(self, raw: ImuSample):
        """One sample through calibration (sensor frame), mounting (sensor → body) and the estimator;
        returns the estimate."""
        c = self.counters
        c.samples += 1
        if self._last_counter is not None:
            missing = raw.counter - self._last_counter - 1
            if missing > 0 or _int_and(raw.flags, _GAP_BEFORE):
                c.gaps += 1
                c.lost_samples += max(missing, 0)
        self._last_counter = raw.counter
        if _int_and(raw.flags, _INVALID):
            c.invalid_samples += 1
        sample = self.calibration.apply(raw)
        self.last_sensor_sample = sample
        m = self.mounting
        if m is not None:
            sample = ImuSample(sample.t_s, m @ sample.gyro_rad_s, m @ sample.accel_m_s2, m @ sample.mag_ut,
                               sample.temp_c, sample.supply_v, sample.flags, sample.diag_stat, sample.counter)
        self.last_sample = sample
        try:
            est = self.estimator.update(sample)
        except (ValueError, FloatingPointError, np.linalg.LinAlgError) as exc:
            c.estimator_errors += 1
            if c.estimator_errors in (1, 100, 10000):
                log.error("estimator rejected sample %d: %s; resetting it", raw.counter, exc)
            self.estimator.reset()
            return None
        self.last_estimate = est
        return est


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
    # reader then probes a little earlier until it meets a stale read (≈ 1 extra read per 100 samples).
    LO_LEAK_S_PER_S = 1e-3
    GUARD_S = 50e-6         # read this much after the predicted ready time

    def __init__(self, period_s: float):
        self.period_s = period_s
        self.lo: float | None = None   # φ > lo
        self.hi: float | None = None   # φ ≤ hi
        self.k = -1                    # index of the last fresh sample
        self._t_lo = 0.0
        self._t_hi = 0.0

    def _leak(self, now: float) -> None:
        self.hi += self.HI_LEAK_S_PER_S * (now - self._t_hi)
        self.lo = max(self.lo - self.LO_LEAK_S_PER_S * (now - self._t_lo), self.hi - self.period_s)  # φ mod P
        self._t_hi = self._t_lo = now

    ambiguous_reads = 0     # fresh reads whose index was not unique (the largest allowed was taken)
    ambiguous_samples = 0   # lost samples counted at those reads that may be phantoms (upper bound)

    def fresh(self, read_time: float, read_end: float | None = None) -> tuple[float, int, int]:
        """A new sample was read by a transfer between `read_time` and `read_end` (default: the same):
        its (t_s, index, samples lost before it)."""
        P = self.period_s
        end = read_time if read_end is None else read_end
        if self.hi is None:
            # Sample 0 is the newest at the latch, so φ lies in (read_time − P, end]. A bracket wider than one
            # period would be cut at hi − P by the next leak, i.e. at the later phase, which indexes every
            # later read one low if the sample became ready during the transfer. Cut it at the earlier phase
            # instead (φ ≤ read_time): at worst one phantom loss, counted as ambiguous.
            self.hi, self.lo, self.k = read_time, read_time - P, 0
            self._t_hi = self._t_lo = read_time
            if end > read_time:
                self.ambiguous_reads += 1
                self.ambiguous_samples += 1
            return read_time, 0, 0
        self._leak(read_time)
        # the latest k with ready_k ≤ end for some φ in (lo, hi]: the largest k with end − k·P > lo
        first = self.k + 1
        k = max(first, math.ceil((end - self.lo) / P) - 1)
        if k > first:
            k_min = max(first, math.floor((read_time - self.hi) / P))   # ready_k ≤ read_time even at φ = hi
            if k > k_min:
                self.ambiguous_reads += 1
                self.ambiguous_samples += k - k_min
        lost = k - self.k - 1
        self.k = k
        self._consumed_upto = -1
        self.hi = min(self.hi, end - k * P)
        if self.lo >= self.hi:                       # only after k was forced up: trust the newest read
            self.lo = self.hi - 0.25 * P
        return self.hi + k * P, k, lost

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
