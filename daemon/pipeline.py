"""The per-sample path: sensor sample → calibration (sensor frame) → mounting rotation (sensor → body) → estimator.

Calibrations are made in the sensor frame (bench calibrations, `ahrsd calibrate`, the field mag-cal session),
so the calibration sees the driver's sensor-frame values; the mounting rotation (sensor → body) comes after
it. Samples come from a drivers.source.SensorSource.

`Pipeline.process_block(block)` is the hot path (every sample goes through it, one sample as a block of one:
`process`): it must stay cheap, so calibration and mounting are applied to the block's (n, 9) vectors in one
product and ONE calibrated body-frame ImuSample is built per sample, gaps are counted from the source's
GAP_BEFORE (the source detects them), and calibration/estimator swaps are single attribute assignments, which the
single-threaded event loop makes atomic between two samples.
"""

from __future__ import annotations

import functools
import logging
import math
import operator
from dataclasses import dataclass

import numpy as np

from ahrsd.core.sample import ImuSample, SampleFlags
from ahrsd.core.sample_block import SampleBlock, sample_flags
from ahrsd.estimator.base import BlockSteppingEstimator, SteppingEstimator
from ahrsd.estimator.rotations import euler_to_dcm

log = logging.getLogger(__name__)

INVALID = SampleFlags.GYRO_INVALID | SampleFlags.ACCEL_INVALID | SampleFlags.MAG_INVALID
# IntFlag operators are slow (enum machinery); the per-sample path tests bits on plain ints
_INVALID, _GAP_BEFORE = int(INVALID), int(SampleFlags.GAP_BEFORE)
_COUNTED = _INVALID | _GAP_BEFORE          # a sample flagged with either takes the counters' slow path
_REJECTED = (ValueError, FloatingPointError, np.linalg.LinAlgError)   # what an estimator raises for a bad sample
or_all = functools.partial(functools.reduce, operator.or_)    # the OR of a run's flag bits, in C (sample_reader too)


def mounting_matrix(rpy_deg) -> np.ndarray | None:
    """Body←sensor DCM from ZYX Euler angles of the sensor axes in the body frame; None for the identity."""
    r, p, y = (math.radians(float(a)) for a in rpy_deg)
    if r == p == y == 0.0:
        return None
    return euler_to_dcm(r, p, y)    # C = Rz(yaw) · Ry(pitch) · Rx(roll), the same ZYX convention as C_b^n


@dataclass
class PipelineCounters:
    samples: int = 0
    gaps: int = 0                # discontinuities in the sample counter (one per gap)
    lost_samples: int = 0        # samples missing inside those gaps
    invalid_samples: int = 0     # samples flagged GYRO/ACCEL/MAG_INVALID
    estimator_errors: int = 0


class Pipeline:
    """Sensor sample in, calibrated body-frame sample and attitude estimate out."""

    def __init__(self, estimator, calibration, mounting: np.ndarray | None = None):
        self.estimator = estimator
        self.calibration = calibration
        self.mounting = mounting
        self.counters = PipelineCounters()
        self.last_sample: ImuSample | None = None    # calibrated, body frame
        # the last sample as the source gave it (what a new calibration would take): (block, row), its
        # ImuSample built only when asked for (last_raw_sample)
        self._raw: tuple | None = None
        self._view = None                  # the estimator's in-place view of its latest estimate (step())
        self._snapshot = None              # the immutable AttitudeEstimate of _view, built on demand
        self._last_counter: int | None = None
        self.last_sample_t_s: float | None = None     # the last sample's time stamp (the sensor's clock)
        # the last sample calibrated in the sensor frame: (block, row, calibration), built when asked for
        self._sensor: tuple | None = None
        self._sensor_sample: ImuSample | None = None
        # process_block(whole_runs=True): the run just yielded, (first row, stop row, its estimate flag bits) and
        # its calibrated body-frame rows; None when the estimate yielded is one sample's
        self.run: tuple[int, int, list] | None = None
        self.run_rows: np.ndarray | None = None
        self._run_block: tuple | None = None     # (block, first, stop, calibration) of that run

    @property
    def estimator(self):
        return self._estimator

    @estimator.setter
    def estimator(self, estimator) -> None:
        self._estimator = estimator
        # the cheap hot path where the estimator has one (estimator.base.SteppingEstimator), and its block step
        # where it has that too (ins: Ins.step_block)
        self._step = estimator.step if isinstance(estimator, SteppingEstimator) else None
        self._step_block = estimator.step_block if isinstance(estimator, BlockSteppingEstimator) else None

    def set_mounting(self, rpy_deg) -> None:
        self.mounting = mounting_matrix(rpy_deg)

    @property
    def last_sensor_sample(self) -> ImuSample | None:
        """The last sample calibrated but still in the sensor frame (before the mounting rotation); built on
        demand (the field mag-cal fits in the sensor frame), the same object as last_sample without a mounting."""
        if self.mounting is None:
            return self.last_sample
        if self._sensor_sample is None and self._sensor is not None:
            block, i, cal = self._sensor               # row i of a block, with the calibration it was given
            raw = block[i]
            if cal.is_identity:
                self._sensor_sample = raw
            else:
                r = _calibrated_rows(block.vectors[i:i + 1], cal, None)[0]     # the block map without the mounting
                self._sensor_sample = ImuSample(raw.t_s, r[0:3], r[3:6], r[6:9], raw.temp_c, raw.supply_v, raw.flags,
                                               raw.diag_stat, raw.counter)
        return self._sensor_sample

    def run_sensor_rows(self) -> np.ndarray:
        """The run just yielded (`process_block(whole_runs=True)`) calibrated but still in the sensor frame (before
        the mounting): (n, 9) rows, each bit for bit the vectors `last_sensor_sample` gives for its sample."""
        block, first, stop, cal = self._run_block
        raw9 = block.vectors[first:stop]
        if cal.is_identity:
            return raw9
        return _calibrated_rows(raw9, cal, None, row_by_row=True)

    @property
    def last_raw_sample(self) -> ImuSample | None:
        """The last sample as the source gave it (sensor frame, uncalibrated): what a new calibration is applied
        to (calibration_heading_change.py)."""
        if self._raw is None:
            return None
        block, i = self._raw
        return block[i]

    @property
    def last_estimate(self):
        """The latest AttitudeEstimate (immutable), built only when someone asks: the publishers at their
        rates, not the reader at 819.2 SPS (the estimator's `step` view is read in place meanwhile)."""
        if self._snapshot is None and self._view is not None:
            self._snapshot = self._view.snapshot()
        return self._snapshot

    def process(self, raw: ImuSample):
        """One sample through calibration (sensor frame), mounting (sensor → body) and the estimator (`process_block`
        of a block of it); returns the estimate: the estimator's in-place view when it has `step` (read it now, or
        take `last_estimate` to keep it), else its AttitudeEstimate."""
        return next(self.process_block(SampleBlock.of((raw,))))

    def process_block(self, block: SampleBlock, stepped_ahead: bool = False, whole_runs: bool = False):
        """Every sample of `block` through calibration, mounting and the estimator, in order, as a generator:
        yields each sample's estimate (read it before the next one). The block's vectors are calibrated and
        rotated at once, one (n, 9) · (9, 9) product (`block_map`: the calibration's affine maps followed by the
        mounting), and only the calibrated ImuSample of each row is built. A calibration or mounting swapped
        between two samples (a listener's) takes effect from the next one.

        `stepped_ahead`: the caller allows the estimator to step a run of the block's samples in one call, before
        their estimates are yielded (an estimator with `step_block`: Ins.step_block). Each sample's estimate then
        carries that sample's time and flags, but a snapshot built from it (`last_estimate`) is that of the run's
        last sample, and a calibration swapped meanwhile applies from the run's end: allowed only where nothing
        does either while the block is processed (daemon.sample_reader: its listeners say so).

        `whole_runs` (with `stepped_ahead`): a run is yielded once, its estimate left at its last sample, with
        `run` (first row, stop row, the run's estimate flag bits) and `run_rows` (its calibrated rows) set; the
        counters, the last sample and the rest come out as if each of its samples had been yielded (only the
        last one's ImuSample is built). `run` is None at a yield of one sample. For a caller whose listeners all
        take runs (daemon.sample_reader.SampleListeners `runs=`)."""
        t_s, temp_c, supply_v, diag, counter = block.t_s, block.temp_c, block.supply_v, block.diag_stat, block.counter
        raw_flags = block.flags
        c = self.counters
        cal = m = None
        step_block = self._step_block if stepped_ahead else None
        if step_block is not None:
            t_arr = np.array(t_s, dtype=np.float64)      # the kernel's types (Ins.step_block)
            flags_arr = np.array(raw_flags, dtype=np.int64)
        ahead = 0                 # the samples below it were stepped in a run (their flags: run_flags[i - run_first])
        if whole_runs:
            self.run = None
        # every sample of the daemon (819.2 a second) goes through this loop: the counting and the estimator's
        # step are written out in it, one Python call each fewer per sample; only a flagged sample (a gap, an
        # invalid axis), a rejected one or an estimator without `step` take a call
        for i in range(len(t_s)):
            if whole_runs and i < ahead:               # taken with its run
                continue
            if self.calibration is not cal or self.mounting is not m:
                cal, m = self.calibration, self.mounting
                rows = _calibrated_rows(block.vectors[i:], cal, m)     # row k is sample i + k
                first = i
            r = rows[i - first]
            flags = raw_flags[i]
            c.samples += 1
            if flags & _COUNTED:                      # plain ints (SampleBlock.flags): no IntFlag machinery
                self._count_flagged(flags, counter[i])
            self._last_counter = counter[i]
            self.last_sample_t_s = t_s[i]
            self._raw = (block, i)
            if m is not None:
                self._sensor, self._sensor_sample = (block, i, cal), None
            sample = self.last_sample = ImuSample(t_s[i], r[0:3], r[3:6], r[6:9], temp_c[i], supply_v[i],
                                                  sample_flags(flags), diag[i], counter[i])
            if step_block is not None and i >= ahead:
                run = step_block(t_arr[i:], np.ascontiguousarray(rows[i - first:]), flags_arr[i:])
                if run is None:              # the estimator steps one by one for now: the rest of the block so
                    step_block = None
                else:
                    run_flags, view = run
                    run_first, ahead = i, i + len(run_flags)
                    if whole_runs and ahead > i:
                        self._took_run(block, i, ahead, rows[i - first:ahead - first], cal, m)
                        view.set(t_s[ahead - 1], run_flags[-1], True)
                        self._view, self._snapshot = view, None
                        self.run = (i, ahead, run_flags)
                        yield view
                        self.run = None
                        continue
            if i < ahead:
                view.set(t_s[i], run_flags[i - run_first], True)
                self._view, self._snapshot = view, None
                yield view
                continue
            step = self._step
            if step is None:
                yield self._estimate(sample)
                continue
            try:
                est = step(sample)
            except _REJECTED as exc:
                yield self._rejected(sample, exc)
                continue
            self._view, self._snapshot = est, None
            yield est

    def _took_run(self, block: SampleBlock, i: int, stop: int, rows: np.ndarray, cal, m) -> None:
        """Rows i + 1 … stop − 1 of `block` stepped in a run with row i (whose part the loop did): what the loop
        does at each of them, at once — counted (a flagged one as the loop counts it, against the counter before
        it), the last one the last sample (its calibrated ImuSample built)."""
        self.run_rows = rows
        self._run_block = (block, i, stop, cal)
        if stop - i < 2:
            return
        raw_flags, counter, t_s = block.flags, block.counter, block.t_s
        self.counters.samples += stop - i - 1
        if or_all(raw_flags[i + 1:stop]) & _COUNTED:
            for j in range(i + 1, stop):
                if raw_flags[j] & _COUNTED:
                    self._last_counter = counter[j - 1]
                    self._count_flagged(raw_flags[j], counter[j])
        j = stop - 1
        self._last_counter = counter[j]
        self.last_sample_t_s = t_s[j]
        self._raw = (block, j)
        if m is not None:
            self._sensor, self._sensor_sample = (block, j, cal), None
        r = rows[-1]
        self.last_sample = ImuSample(t_s[j], r[0:3], r[3:6], r[6:9], block.temp_c[j], block.supply_v[j],
                                     sample_flags(raw_flags[j]), block.diag_stat[j], counter[j])

    def _count_flagged(self, flags: int, counter: int) -> None:
        """A flagged sample's share of the counters besides `samples`: a gap the source found (its size from the
        counter, against the previous sample's), invalid."""
        c = self.counters
        if flags & _GAP_BEFORE:                  # the source found the gap; its size is in the counter
            c.gaps += 1
            last = self._last_counter
            if last is not None and counter > last + 1:
                c.lost_samples += counter - last - 1
        if flags & _INVALID:
            c.invalid_samples += 1

    def _estimate(self, sample: ImuSample):
        """The calibrated body-frame sample (already `last_sample`) through an estimator without `step` (reset when
        it rejects the sample)."""
        try:
            est = self._estimator.update(sample)
        except _REJECTED as exc:
            return self._rejected(sample, exc)
        self._view, self._snapshot = None, est
        return est

    def _rejected(self, sample: ImuSample, exc: Exception) -> None:
        """The estimator rejected the sample: counted, logged now and then, the estimator reset."""
        c = self.counters
        c.estimator_errors += 1
        if c.estimator_errors in (1, 100, 10000):
            log.error("estimator rejected sample %d: %s; resetting it", sample.counter, exc)
        self._estimator.reset()


def block_map(cal, m: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """(K, o) with body-frame [gyro, accel, mag] = K · raw9 − o for a raw9 of [gyro, accel, mag] (the accel's
    quadratic term taken off first): the calibration's three affine maps (calibration/models.py: M · (raw − b))
    side by side in one 9 × 9 block-diagonal K, each followed by the mounting rotation C."""
    c = np.eye(3) if m is None else m
    k = np.zeros((9, 9))
    o = np.empty(9)
    for j, (matrix, bias) in enumerate(((cal.gyro.matrix, cal.gyro.bias_rad_s), (cal.accel.matrix, cal.accel.bias_m_s2),
                                        (cal.mag.soft_iron, cal.mag.hard_iron_ut))):
        cm = c @ matrix
        k[3 * j:3 * j + 3, 3 * j:3 * j + 3] = cm
        o[3 * j:3 * j + 3] = cm @ bias
    return k, o


_BLOCK_MAPS: dict = {}          # (calibration, mounting) ids → their (Kᵀ, o): swaps are rare, blocks 200 a second


def _calibrated_rows(raw9: np.ndarray, cal, m: np.ndarray | None, row_by_row: bool = False) -> np.ndarray:
    """The calibrated, body-frame (n, 9) rows of raw (n, 9) rows. `row_by_row`: each row's product made as a one-row
    product, stacked ((n, 1, 9) · (9, 9): numpy's matmul runs its one-row loop for each), so a row is bit for bit
    what the rows one at a time give; the (n, 9) product takes another BLAS kernel, whose last bits differ."""
    if cal.is_identity and m is None:
        return raw9
    key = (id(cal), id(m))
    entry = _BLOCK_MAPS.get(key)
    if entry is None or entry[0] is not cal or entry[1] is not m:
        if len(_BLOCK_MAPS) > 16:
            _BLOCK_MAPS.clear()
        k, o = block_map(cal, m)
        q = cal.accel.quadratic
        entry = _BLOCK_MAPS[key] = (cal, m, np.ascontiguousarray(k.T), o, q if np.any(q) else None)
    q = entry[4]
    if q is not None:
        raw9 = raw9.copy()
        a = raw9[:, 3:6]
        a -= q * a * a                                   # f − q∘f² (AccelModel), before the matrix
    if row_by_row:
        out = (raw9[:, None, :] @ entry[2])[:, 0, :]
    else:
        out = raw9 @ entry[2]                            # rows: (K · raw9)ᵀ = raw9ᵀ · Kᵀ
    out -= entry[3]
    return out
